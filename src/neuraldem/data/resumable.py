"""Training samples that a resumed run draws exactly as an uninterrupted one.

Epoch e's order is a function of (seed, e) only: a permutation, or draws with replacement from fixed weights.
Sample j of epoch e carries the draw number e * len + j, which seeds that sample's own randomness (query
points, subsets, noise). Neither depends on torch's global RNG, the number of loader workers or how far ahead
Lightning prefetches, so a run resumed at batch b of epoch e (`skip_next`, set by
`neuraldem.lit.resume.ExactResume`) sees the very samples the uninterrupted run saw from there on.

Data-parallel training (W processes, `rank` r) deals the same order out: process r takes positions
r, r + W, r + 2W, ... of each epoch, with the draw numbers of those positions. With the per-process batch
b = B / W, batch i of process r is positions iB + r + W j (j < b), so the W processes of step i together train on
exactly the samples of batch i of a one-process run with batch B (`neuraldem.lit.distributed`).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import NamedTuple

import numpy as np
import torch
from torch.utils.data import Sampler


class Draw(NamedTuple):
    """A training sample's dataset index and its draw number (unique within a run)."""

    index: int
    draw: int


class ResumableSampler(Sampler[Draw]):
    """`n` samples per epoch in a seeded order: a permutation, or with `weights` draws with replacement.
    With `world` > 1 processes, process `rank` gets every `world`-th position from position `rank` on (n // world
    of them: the last n % world positions of an epoch go to nobody, as a one-process run with a batch divisible
    by `world` drops them with its last partial batch)."""

    def __init__(self, n: int, seed: int, weights: np.ndarray | torch.Tensor | None = None, rank: int = 0,
                 world: int = 1):
        self.n, self.seed, self.epoch, self._skip = int(n), int(seed), 0, 0
        if not (int(world) >= 1 and 0 <= int(rank) < int(world)):
            raise ValueError(f"rank {rank} of {world} processes: need 0 <= rank < world")
        self.rank, self.world = int(rank), int(world)
        if weights is not None:
            w = np.asarray(weights, dtype=np.float64)
            if w.shape != (self.n,) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
                raise ValueError(f"weights must be {self.n} finite non-negative numbers with a positive sum")
            weights = w / w.sum()
        self.weights = weights

    def set_epoch(self, epoch: int) -> None:
        """Called by Lightning at the start of every epoch."""
        self.epoch = int(epoch)

    def skip_next(self, n_samples: int) -> None:
        """The next pass starts at sample `n_samples` of its epoch (a resumed run's place; this process's
        samples); later passes at 0."""
        self._skip = max(0, int(n_samples))

    def order(self, epoch: int) -> np.ndarray:
        rng = np.random.default_rng([self.seed, epoch])
        if self.weights is None:
            return rng.permutation(self.n)
        return rng.choice(self.n, size=self.n, replace=True, p=self.weights)

    def __len__(self) -> int:
        return self.n // self.world

    def __iter__(self) -> Iterator[Draw]:
        # a generator: Lightning creates the loader's iterator before it sets the epoch, and nothing here runs
        # until the first sample is asked for
        start, self._skip = self._skip, 0
        order = self.order(self.epoch)
        for i in range(start, len(self)):
            j = self.rank + self.world * i  # the position in the epoch's order (one process: j = i)
            yield Draw(int(order[j]), self.epoch * self.n + j)


def sample_rng(seed: int, draw: int) -> np.random.Generator:
    """The randomness of one training sample: a function of the data seed and the draw number alone."""
    return np.random.default_rng([seed, draw, 1])


def loader_generator(seed: int) -> torch.Generator:
    """A private generator for a DataLoader: creating its iterator draws a worker base seed, which would
    otherwise come from (and advance) torch's global RNG at a moment a resumed run cannot reproduce."""
    return torch.Generator().manual_seed(int(seed))
