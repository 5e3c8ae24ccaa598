"""`neuraldem evaluate rollout ckpt=PATH velocity=V steps=N`: roll a trained model forward in time.

The checkpoint's scene does the work (`Scene.rollout`; the fluidized bed: autoregressive rollout from a stored
snapshot, stopped at the first unphysical state, rollout.h5 + rollout.json + a ParaView series in the run
folder). Exit status: 0 finished, 1 diverged (the states before the divergence are written), 2 bad input.
"""

from __future__ import annotations

import sys
from pathlib import Path

from omegaconf import DictConfig

from neuraldem.cli import hydra_app
from neuraldem.config import checks
from neuraldem.errors import ConfigError
from neuraldem.eval.checkpoints import checkpoint_metadata
from neuraldem.scenes import registry, scene


@hydra_app("rollout")
def main(cfg: DictConfig) -> None:
    checks.required(cfg, "rollout", {"ckpt": "ckpt=<run>/checkpoints/last.ckpt", "velocity": "velocity=1.6"})
    kind = checkpoint_metadata(Path(cfg.ckpt)).get("kind")
    rollout = scene(kind, key=f"the kind of {cfg.ckpt}").rollout
    if rollout is None:
        able = [s.kind for s in registry().values() if s.rollout is not None]
        raise ConfigError(f"{cfg.ckpt} is a {kind} model, which has no time-stepping rollout",
                          f"roll out a model of {', '.join(able)}")
    if not rollout(cfg):
        sys.exit(1)


if __name__ == "__main__":
    main()
