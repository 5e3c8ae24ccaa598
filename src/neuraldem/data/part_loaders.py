"""A LightningDataModule base whose train/val/test loaders come from `self.datasets[part]`."""

from __future__ import annotations

import math
import warnings
from typing import Any

import lightning as L
import numpy as np
from lightning.pytorch.utilities.warnings import PossibleUserWarning
from torch.utils.data import DataLoader

from neuraldem.data.resumable import ResumableSampler, loader_generator


class PartLoaders(L.LightningDataModule):
    """Subclasses set `datasets` (part -> Dataset), `batch_size`, `num_workers` and `seed` in setup. A part
    without samples gives no loader (an empty list: Lightning skips it); training drops a last partial batch
    only when there is a whole one. `loader_class` is the DataLoader to use (torch_geometric's for graph samples).

    The training order comes from a `ResumableSampler` (weighted when `train_weights` returns weights), and
    the checkpoint stores where in it training was (`state_dict`): a resumed run's loader starts at that
    batch, before any worker prefetches, so it continues with the samples an uninterrupted run would draw."""

    loader_class: type = DataLoader
    datasets: dict
    batch_size: int
    num_workers: int
    seed: int
    _resume_at: dict[str, int] | None = None

    def train_weights(self) -> np.ndarray | None:
        """Sampling weights of the training samples; None draws each once per epoch."""
        return None

    def _loader(self, part: str) -> DataLoader | list:
        dataset, train = self.datasets[part], part == "train"
        if not len(dataset):
            return []
        sampler = ResumableSampler(len(dataset), self.seed, self.train_weights()) if train else None
        drop_last = train and len(dataset) >= self.batch_size
        if sampler is not None and self._resume_at is not None:
            self._position(sampler, len(dataset) // self.batch_size if drop_last
                           else math.ceil(len(dataset) / self.batch_size))
        return self.loader_class(dataset, batch_size=self.batch_size, sampler=sampler,
                                 num_workers=self.num_workers, persistent_workers=self.num_workers > 0,
                                 drop_last=drop_last, generator=loader_generator(self.seed))

    def _position(self, sampler: ResumableSampler, n_batches: int) -> None:
        at, self._resume_at = self._resume_at or {}, None
        epoch, done = at["epoch"], at["batches_done"]
        if done >= n_batches:  # saved at the end of an epoch: the next one starts afresh
            epoch, done = epoch + 1, 0
        sampler.set_epoch(epoch)
        sampler.skip_next(done * self.batch_size)

    def state_dict(self) -> dict[str, Any]:
        """Where training is: the epoch and the batches of it whose step has run (written with checkpoints)."""
        trainer = self.trainer
        if trainer is None or trainer.state.fn != "fit":
            return {}
        done = trainer.fit_loop.epoch_loop.batch_progress.current.processed
        return {"train_position": {"epoch": int(trainer.current_epoch), "batches_done": int(done)}}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self._resume_at = state_dict.get("train_position")
        if self._resume_at:  # the loader does resume mid-epoch, through its sampler: Lightning cannot see that
            warnings.filterwarnings("ignore", message="You're resuming from a checkpoint that ended before",
                                    category=PossibleUserWarning)

    def train_dataloader(self) -> DataLoader | list:
        return self._loader("train")

    def val_dataloader(self) -> DataLoader | list:
        return self._loader("val")

    def test_dataloader(self) -> DataLoader | list:
        return self._loader("test")
