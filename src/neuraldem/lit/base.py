"""The part every neuraldem LightningModule shares: one step that scores a batch and logs it, the same for
training, validation and test, and the optimizer (LION with warm-up + cosine, `lit.optim`). A module says what
the losses of a batch are (`stage_losses`, with the total under "loss") and how many samples it holds."""

from __future__ import annotations

from typing import Any

import lightning as L
import torch

from neuraldem.lit.optim import lion_warmup_cosine


class SurrogateModule(L.LightningModule):
    opt_cfg: dict[str, Any]
    sched_cfg: dict[str, Any]

    def stage_losses(self, batch: Any, stage: str) -> dict[str, torch.Tensor]:
        """The losses of `batch` in `stage` (train / val / test): the optimised total under "loss"."""
        raise NotImplementedError

    def batch_size(self, batch: Any) -> int:
        return int(batch["scalars"].shape[0])

    def _step(self, batch: Any, stage: str) -> torch.Tensor:
        """Per step while training (the progress bar follows it), per epoch in validation and test."""
        losses = self.stage_losses(batch, stage)
        train, bs = stage == "train", self.batch_size(batch)
        self.log(f"{stage}/loss", losses["loss"], prog_bar=True, batch_size=bs, on_step=train, on_epoch=not train)
        parts = {f"{stage}/{k}": v for k, v in losses.items() if k != "loss"}
        if parts:
            self.log_dict(parts, batch_size=bs, on_step=train, on_epoch=not train)
        return losses["loss"]

    def training_step(self, batch: Any, batch_idx: int) -> torch.Tensor:
        return self._step(batch, "train")

    def validation_step(self, batch: Any, batch_idx: int) -> None:
        self._step(batch, "val")

    def test_step(self, batch: Any, batch_idx: int) -> None:
        self._step(batch, "test")

    def configure_optimizers(self) -> dict[str, Any]:
        return lion_warmup_cosine(self.parameters(), self.opt_cfg, self.sched_cfg, self.trainer.max_steps)
