"""Base of the datasets that read their samples from one HDF5 file per simulation."""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset


class FileSamples(Dataset):
    """Keeps up to 64 files open per process (DataLoader workers reopen their own: open h5py handles do not
    pickle) and draws each sample's randomness fresh in training, or from (seed, index) otherwise so that
    validation and test see the same points every epoch."""

    def __init__(self, random: bool, seed: int):
        self.random = random
        self.seed = seed
        self._open = lru_cache(maxsize=64)(self._open_file)

    def _open_file(self, s: int) -> Any:
        raise NotImplementedError

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state.pop("_open")
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._open = lru_cache(maxsize=64)(self._open_file)

    def _rng(self, i: int) -> np.random.Generator:
        if self.random:
            return np.random.default_rng(int(torch.randint(0, 2**62, ()).item()))
        return np.random.default_rng([self.seed, i])
