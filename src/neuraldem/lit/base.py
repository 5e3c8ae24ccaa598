"""The part every neuraldem LightningModule shares: one step that scores a batch and logs it, the same for
training, validation and test, and the optimizer (LION with warm-up + cosine, `lit.optim`). A module says what
the losses of a batch are (`stage_losses`, with the total under "loss") and how many samples it holds.

Data-parallel training (`lit.distributed`) trains as one process would: random draws inside a training step
come from `training_draws()`, masked means divide by `shared_count`, statistics kept across steps are
averaged with `mean_over_ranks`; a logged training loss is the mean over the processes, a validation or test
loss the mean over the epoch's samples of all processes (summed here: Lightning's own synced mean rounds the
sample count down when it does not divide by the number of processes)."""

from __future__ import annotations

from typing import Any

import lightning as L
import torch

from neuraldem.lit.distributed import TrainingDraws
from neuraldem.lit.optim import lion_warmup_cosine


class SurrogateModule(L.LightningModule):
    opt_cfg: dict[str, Any]
    sched_cfg: dict[str, Any]
    _draw_seed: int = 0
    _epoch_sums: dict[str, torch.Tensor] | None = None
    _epoch_count: int = 0

    def stage_losses(self, batch: Any, stage: str) -> dict[str, torch.Tensor]:
        """The losses of `batch` in `stage` (train / val / test): the optimised total under "loss"."""
        raise NotImplementedError

    def batch_size(self, batch: Any) -> int:
        return int(batch["scalars"].shape[0])

    def _step(self, batch: Any, stage: str) -> torch.Tensor:
        """Logged per step while training (the progress bar follows it), per epoch in validation and test (the
        mean over samples of the batch means, `_log_epoch_means`)."""
        losses = self.stage_losses(batch, stage)
        bs = self.batch_size(batch)
        if stage == "train":
            self.log("train/loss", losses["loss"], prog_bar=True, batch_size=bs, on_step=True, on_epoch=False,
                     sync_dist=True)
            parts = {f"train/{k}": v for k, v in losses.items() if k != "loss"}
            if parts:
                self.log_dict(parts, batch_size=bs, on_step=True, on_epoch=False, sync_dist=True)
        else:
            sums = self._epoch_sums if self._epoch_sums is not None else {}
            for k, v in losses.items():
                sums[k] = sums.get(k, 0.0) + v.detach().to(self._sum_dtype()) * bs
            self._epoch_sums, self._epoch_count = sums, self._epoch_count + bs
        return losses["loss"]

    def _log_epoch_means(self, stage: str) -> None:
        sums, count, self._epoch_sums, self._epoch_count = self._epoch_sums, self._epoch_count, None, 0
        if not sums:
            return
        keys = sorted(sums)
        totals = torch.stack([sums[k] for k in keys] + [torch.tensor(float(count), device=self.device,
                                                                     dtype=self._sum_dtype())])
        if self._trainer is not None and self.trainer.world_size > 1:  # every process holds the same keys
            totals = self.trainer.strategy.reduce(totals, reduce_op="sum")
        means = {f"{stage}/{k}": (totals[i] / totals[-1]).float() for i, k in enumerate(keys)}
        # already the mean over all processes: the same value everywhere (so syncing it changes nothing)
        self.log(f"{stage}/loss", means.pop(f"{stage}/loss"), prog_bar=True, on_epoch=True, batch_size=1,
                 sync_dist=True)
        self.log_dict(means, on_epoch=True, batch_size=1, sync_dist=True)

    def _sum_dtype(self) -> torch.dtype:
        return torch.float32 if self.device.type == "mps" else torch.float64  # MPS has no float64

    def on_validation_epoch_start(self) -> None:
        self._epoch_sums, self._epoch_count = None, 0

    def on_validation_epoch_end(self) -> None:
        self._log_epoch_means("val")

    def on_test_epoch_start(self) -> None:
        self._epoch_sums, self._epoch_count = None, 0

    def on_test_epoch_end(self) -> None:
        self._log_epoch_means("test")

    def training_step(self, batch: Any, batch_idx: int) -> torch.Tensor:
        return self._step(batch, "train")

    def validation_step(self, batch: Any, batch_idx: int) -> None:
        self._step(batch, "val")

    def test_step(self, batch: Any, batch_idx: int) -> None:
        self._step(batch, "test")

    def configure_optimizers(self) -> dict[str, Any]:
        return lion_warmup_cosine(self.parameters(), self.opt_cfg, self.sched_cfg, self.trainer.max_steps)

    # ---- training as one process would, with any number of processes
    def on_fit_start(self) -> None:
        # the seed of the training draws: rank 0's, so that every process draws alike
        self._draw_seed = int(self.trainer.strategy.broadcast(torch.initial_seed()))

    def _in_training_step(self) -> bool:
        trainer = self._trainer
        return trainer is not None and trainer.training

    def training_draws(self) -> TrainingDraws | None:
        """The draws of the current training batch (`lit.distributed.TrainingDraws`); None outside a training
        step, where a module draws from torch's global RNG."""
        if not self._in_training_step():
            return None
        trainer = self.trainer
        return TrainingDraws(self._draw_seed, trainer.fit_loop.total_batch_idx, trainer.global_rank,
                             trainer.world_size, self.device)

    def _distributed_training(self) -> bool:
        return self._in_training_step() and self.trainer.world_size > 1

    def shared_count(self, count: torch.Tensor) -> torch.Tensor:
        """What a masked mean over this process's points divides by: their count, or while training with several
        processes the mean count over the processes, so that averaging the processes' losses (and gradients, as
        DDP does) gives sum over all points / their total count, the one-process mean of the global batch."""
        if not self._distributed_training():
            return count
        return self.trainer.strategy.reduce(count.detach().clone().float(), reduce_op="mean")

    def mean_over_ranks(self, value: torch.Tensor) -> torch.Tensor:
        """A per-batch statistic (a mean over equal-sized batches) as the whole global batch's: the mean over the
        processes while training with several, else `value` itself."""
        if not self._distributed_training():
            return value
        return self.trainer.strategy.reduce(value.detach().clone(), reduce_op="mean")
