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
from neuraldem.errors import ConfigError


def process_share(trainer: Any) -> tuple[int, int]:
    """(global rank, number of processes) of a trainer; (0, 1) without one."""
    if trainer is None:
        return 0, 1
    return int(trainer.global_rank), int(trainer.world_size)


def rank_batch_size(batch_size: int, world: int, key: str = "data.datamodule.batch_size") -> int:
    """The per-process batch of the global `batch_size` over `world` processes; refused if it does not divide."""
    if world > 1 and batch_size % world:
        ok = max(world, (batch_size // world) * world)
        raise ConfigError(f"config value {key}={batch_size} is invalid: it is the global batch, split evenly over "
                          f"{world} processes (trainer.devices x trainer.num_nodes), so it must be a multiple of "
                          f"{world}", f"override it, e.g. {key}={ok}")
    return batch_size // world


class PartLoaders(L.LightningDataModule):
    """Subclasses set `datasets` (part -> Dataset), `batch_size`, `num_workers` and `seed` in setup. A part
    without samples gives no loader (an empty list: Lightning skips it); training drops a last partial batch
    only when there is a whole one. `loader_class` is the DataLoader to use (torch_geometric's for graph samples).

    The training order comes from a `ResumableSampler` (weighted when `train_weights` returns weights), and
    the checkpoint stores where in it training was (`state_dict`): a resumed run's loader starts at that
    batch, before any worker prefetches, so it continues with the samples an uninterrupted run would draw.

    `batch_size` is the global batch. With W processes (data-parallel training, `lit.distributed`) a training
    loader gives its process batch_size / W samples, its share of the one-process order: the processes'
    batches of a step together are the one-process batch, and a run resumes with any number of processes.
    Validation and test deal out the one-process batches themselves, whole (batch r, r + W, ... to process r;
    all of them to every process when there are fewer than W), so that the epoch means the module logs
    (`SurrogateModule`) are the one-process ones. Lightning must not replace these samplers
    (`trainer.use_distributed_sampler=false`)."""

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
        n = len(dataset)
        if not n:
            return []
        rank, world = process_share(self.trainer)
        workers = {"num_workers": self.num_workers, "persistent_workers": self.num_workers > 0,
                   "generator": loader_generator(self.seed)}
        if not train:
            n_batches = math.ceil(n / self.batch_size)
            if world == 1 or n_batches < world:
                return self.loader_class(dataset, batch_size=self.batch_size, **workers)
            batches = [list(range(i * self.batch_size, min(n, (i + 1) * self.batch_size)))
                       for i in range(rank, n_batches, world)]
            return self.loader_class(dataset, batch_sampler=batches, **workers)
        batch_size = rank_batch_size(self.batch_size, world)
        if world > 1 and n < self.batch_size:
            raise ConfigError(f"config value data.datamodule.batch_size={self.batch_size} is invalid: the training "
                              f"part has only {n} samples, fewer than one global batch for {world} processes",
                              f"override it, e.g. data.datamodule.batch_size={n - n % world}")
        sampler = ResumableSampler(n, self.seed, self.train_weights(), rank=rank, world=world)
        drop_last = n >= self.batch_size
        if self._resume_at is not None:
            self._position(sampler, n // self.batch_size if drop_last else math.ceil(n / self.batch_size),
                           batch_size)
        return self.loader_class(dataset, batch_size=batch_size, sampler=sampler, drop_last=drop_last, **workers)

    def _position(self, sampler: ResumableSampler, n_batches: int, batch_size: int) -> None:
        """`n_batches` per epoch (global batches: as many per process); `batch_size` this process's."""
        at, self._resume_at = self._resume_at or {}, None
        epoch, done = at["epoch"], at["batches_done"]
        if done >= n_batches:  # saved at the end of an epoch: the next one starts afresh
            epoch, done = epoch + 1, 0
        sampler.set_epoch(epoch)
        sampler.skip_next(done * batch_size)

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
