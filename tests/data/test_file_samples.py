"""The shared dataset base: it pickles without its open files (DataLoader workers), reopens on demand, and
draws the same points per index when not random."""

from __future__ import annotations

import pickle

import numpy as np

from neuraldem.data.file_samples import FileSamples


class Opened(FileSamples):
    def _open_file(self, s: int) -> list[int]:
        return [s]  # stands in for an open HDF5 file (test double)


def test_pickles_without_open_files_and_reopens():
    ds = Opened(random=False, seed=3)
    first = ds._open(1)
    assert ds._open(1) is first  # cached
    copy = pickle.loads(pickle.dumps(ds))
    assert copy._open(1) == [1] and copy._open(1) is not first


def test_fixed_draws_per_index_unless_random():
    fixed = Opened(random=False, seed=3)
    assert np.array_equal(fixed._rng(5).random(4), fixed._rng(5).random(4))
    assert not np.array_equal(fixed._rng(5).random(4), fixed._rng(6).random(4))
    fresh = Opened(random=True, seed=3)
    assert not np.array_equal(fresh._rng(5).random(4), fresh._rng(5).random(4))
