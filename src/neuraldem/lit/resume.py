"""ExactResume: a run killed and resumed from its checkpoint continues as if it had never stopped.

Lightning's checkpoint holds the weights, the optimizer, the schedule and the loop counters; the datamodule
(`data.part_loaders.PartLoaders`) stores where in the epoch's sample order training was, and the draws of our
modules' training steps (unroll lengths, input noise, supernode picks) are keyed by the batch number
(`lit.distributed.TrainingDraws`). What is still missing are the global RNG states (torch, numpy, python) for
anything else that draws from them while training (a net of one's own with dropout): this callback writes them
with every checkpoint and puts them back just before the first resumed step. Under DDP the checkpoint holds
rank 0's states and every process resumes with them; our modules' draws do not depend on them, so a run resumes
exactly with any number of processes (docs/cluster_training.md).
"""

from __future__ import annotations

import logging
import random
from typing import Any

import lightning as L
import numpy as np
import torch

log = logging.getLogger(__name__)
KEY = "neuraldem_rng_states"


def rng_states() -> dict[str, Any]:
    """The global RNG states as tensors and plain numbers (what Lightning's weights-only load accepts)."""
    numpy = np.random.get_state(legacy=False)
    numpy_state = {"key": torch.from_numpy(numpy["state"]["key"].astype(np.int64)), "pos": int(numpy["state"]["pos"]),
                   "has_gauss": int(numpy["has_gauss"]), "gauss": float(numpy["gauss"])}
    return {"torch": torch.get_rng_state(), "numpy": numpy_state, "python": random.getstate()}


def set_rng_states(states: dict[str, Any]) -> None:
    torch.set_rng_state(states["torch"])
    n = states["numpy"]
    np.random.set_state({"bit_generator": "MT19937", "has_gauss": n["has_gauss"], "gauss": n["gauss"],
                         "state": {"key": n["key"].numpy().astype(np.uint32), "pos": n["pos"]}})
    random.setstate(states["python"])


class ExactResume(L.Callback):
    def __init__(self) -> None:
        self._pending: dict[str, Any] | None = None

    def on_save_checkpoint(self, trainer: L.Trainer, pl_module: L.LightningModule, checkpoint: dict) -> None:
        checkpoint[KEY] = rng_states()

    def on_load_checkpoint(self, trainer: L.Trainer, pl_module: L.LightningModule, checkpoint: dict) -> None:
        self._pending = checkpoint.get(KEY)
        if self._pending is None:
            log.warning("the checkpoint holds no RNG states (written before they were stored): the resumed run's "
                        "random draws differ from an uninterrupted run's")

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # the last hook before the first resumed step: everything that draws while the run is set up comes before
        state, self._pending = self._pending, None
        if state is not None:
            set_rng_states(state)
