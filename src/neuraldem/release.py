"""`neuraldem release [SCENE] ckpt=RUN/checkpoints/last.ckpt name=NAME [out=DIR]`: a model folder for predict.

    neuraldem release ckpt=RUN/checkpoints/last.ckpt name=my_hopper       # into <data dir>/models/my_hopper
    neuraldem release ckpt=RUN/checkpoints/last.ckpt name=my_hopper out=$HOME/my-models
    neuraldem release ckpt=FB_RUN/checkpoints/best.ckpt name=fb_small lacey_time=1 out=src/neuraldem/pretrained
    neuraldem release ckpt=FB_RUN/selected.ckpt name=fb_small test_dataset=fb_small_heldout rollout.rollout_noise=3
    neuraldem release fluidized_bed name=fb_small refresh_field=true   # after a change of the bed rollouts

Writes `<out>/<name>/`: `field.pt` (the checkpoint without optimizer state), the scene's scalar GP as arrays
numpy answers with (`gp.npz`), what else its answers need (a bed's first states), and `meta.json`: the training
data (dataset, SHA-256 of its manifest, the run ids of each part), the config, the test errors of the field
model, the GP and the constant on the checkpoint's held-out test runs, the trained ranges (covered by the runs,
and asked of datagen), answers at probe points and the rebuild commands. The checkpoint says which scene
releases it (`Scene.release`); SCENE is needed only without a checkpoint.

`out=` defaults to your model folder, the first of `NEURALDEM_MODELS` (default `<data dir>/models`), which
`predict`, `scan` and `serve` search before the shipped models: `model=NAME` then answers with it, and
`model=<out>/<name>` works from any folder. The shipped models are built the same way with
`out=src/neuraldem/pretrained`. `refresh_field=true` rewrites the model found under `name=` (or `<out>/<name>`).
A bed model's rollout options (`rollout.rollout_noise=`, `rollout.advection_correction=`,
`rollout.mirror_alternate=`, chosen on validation) go into its field.pt before its test runs are scored;
`test_dataset=` scores a dataset of held-out runs instead of the checkpoint's own test runs (used when those
were read while the recipe was chosen).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

from neuraldem import pretrained
from neuraldem.cli import command_parser, report_user_errors
from neuraldem.errors import ConfigError
from neuraldem.scenes import by_name, registry, scene


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    chosen = by_name(argv.pop(0)) if argv and "=" not in argv[0] and not argv[0].startswith("-") else None
    able = {s.kind: importlib.import_module(s.release) for s in registry().values() if s.release}
    p = command_parser("neuraldem.release", __doc__)
    p.add_argument("--ckpt", type=Path, default=None, help="a checkpoint written by neuraldem train")
    p.add_argument("--name", required=True, help="the model's name (its folder)")
    p.add_argument("--out", type=Path, default=None,
                   help=f"folder the model folder goes into (default: your model folder, {pretrained.ENV_VAR} or "
                        f"<data dir>/models, now {pretrained.release_dir()}; the shipped models: "
                        "out=src/neuraldem/pretrained)")
    p.add_argument("--dataset", type=Path, default=None, help="dataset dir (default: the checkpoint's)")
    p.add_argument("--reuse-test", action="store_true",
                   help="release although the test runs were read for another recipe of the same family (the "
                        "model card says so; new test runs are the honest way)")
    p.add_argument("--card-only", action="store_true",
                   help="write MODEL_CARD.md of a released model again from its meta.json (name=, out=)")
    for module in able.values():
        module.add_options(p)
    args = p.parse_args(argv)
    if args.card_only:  # the card of an already released model, from its meta.json
        import json

        from neuraldem.pretrained.card import write_card

        folder = args.out / args.name
        if not (folder / "meta.json").is_file():
            raise ConfigError(f"card_only=true: {folder} holds no released model (no meta.json)",
                              "give name= and out= of a released model")
        print(f"wrote {write_card(folder)} ({json.loads((folder / 'meta.json').read_text()).get('kind')} model)")
        return 0
    if args.ckpt is not None:
        from neuraldem.eval.checkpoints import checkpoint_metadata

        kind = checkpoint_metadata(args.ckpt).get("kind")
    elif chosen is not None:
        kind = chosen.kind
    else:
        raise ConfigError("ckpt= is required: the checkpoint to release (e.g. ckpt=RUN/checkpoints/last.ckpt)")
    if kind not in able:
        raise ConfigError(f"the {scene(kind).kind} scene has no release", f"release one of {', '.join(able)}")
    if args.out is None and not getattr(args, "refresh_field", False):
        args.out = pretrained.release_dir()
    print(able[kind].release(args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
