"""Base of the datasets that read their samples from one HDF5 file per simulation."""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from neuraldem.data.resumable import Draw, sample_rng


class FileSamples(Dataset):
    """Keeps up to 64 files open per process (DataLoader workers reopen their own: open h5py handles do not
    pickle) and gives each sample its randomness: in training from the sample's draw number (a `Draw` key from
    `ResumableSampler`, so a resumed run repeats it exactly), otherwise from (seed, index) so that validation
    and test see the same points every epoch. Subclasses implement `sample(index, rng)`."""

    def __init__(self, random: bool, seed: int):
        self.random = random
        self.seed = seed
        self._open = lru_cache(maxsize=64)(self._open_file)

    def _open_file(self, s: int) -> Any:
        raise NotImplementedError

    def sample(self, i: int, rng: np.random.Generator) -> Any:
        raise NotImplementedError

    def __getitem__(self, key: int | Draw) -> Any:
        if isinstance(key, Draw):
            return self.sample(key.index, sample_rng(self.seed, key.draw) if self.random else self._rng(key.index))
        return self.sample(key, self._rng(key))

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state.pop("_open")
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._open = lru_cache(maxsize=64)(self._open_file)

    def _rng(self, i: int) -> np.random.Generator:
        if self.random:  # indexed without a draw number (a plain loader): fresh, from torch's global RNG
            return np.random.default_rng(int(torch.randint(0, 2**62, ()).item()))
        return np.random.default_rng([self.seed, i])
