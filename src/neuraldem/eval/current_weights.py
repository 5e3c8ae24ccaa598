"""The raw weights of a checkpoint trained with weight averaging, as a checkpoint of their own.

Why: with `+callbacks.ema._target_=lightning.pytorch.callbacks.EMAWeightAveraging` a checkpoint's `state_dict`
holds the averaged (EMA) weights, and Lightning keeps the weights the optimizer reached at that step beside
them (`current_model_state`). Every tool (evaluate, evaluate rollout, bench, release) reads `state_dict`; this
writes a copy whose `state_dict` is the current weights, so the same run scores both and the average is an
ablation row with everything else equal.

    python -m neuraldem.eval.current_weights src=RUN/checkpoints/step002000.ckpt \\
        dst=RUN/checkpoints/step002000_current.ckpt
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.errors import DataError
from neuraldem.eval.checkpoints import read_checkpoint

AVERAGING_KEYS = ("current_model_state", "averaging_state")


def write_current_weights(src: Path, dst: Path) -> Path:
    """Copy `src` to `dst` with the current (not averaged) weights as its state dict; the averaging's own
    entries are dropped, so `dst` is an ordinary checkpoint."""
    raw = read_checkpoint(src).raw
    if "current_model_state" not in raw:
        raise DataError(f"{src} has no current_model_state: it was not trained with weight averaging, so its "
                        "state_dict already is the current weights (use it as it is)")
    if Path(dst).resolve() == Path(src).resolve():
        raise DataError(f"{dst} is the checkpoint being read: name another output file")
    out = {k: v for k, v in raw.items() if k not in AVERAGING_KEYS and k != "state_dict"}
    out["state_dict"] = dict(raw["current_model_state"])
    Path(dst).parent.mkdir(parents=True, exist_ok=True)
    torch.save(out, dst)
    return Path(dst)


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    p = doc_parser("neuraldem.eval.current_weights", __doc__)
    p.add_argument("src", type=Path, help="a checkpoint written with callbacks.ema (EMAWeightAveraging)")
    p.add_argument("dst", type=Path, help="where the copy with the current weights goes")
    args = p.parse_args(argv)
    print(write_current_weights(args.src, args.dst))


if __name__ == "__main__":
    main(sys.argv[1:])
