"""Compact copies: positions, exits and times come back bit for bit; the copy trains like the original."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neuraldem.data.manifest import Manifest
from neuraldem.errors import DataError
from neuraldem.scenes.hopper.dataset.store import HopperFile
from neuraldem.scenes.hopper.dataset.transfer import decode_positions, encode_positions, pack, unpack
from neuraldem.scenes.hopper.surrogate.datamodule import HopperDataModule


def test_codec_round_trip_with_exits():
    rng = np.random.default_rng(0)
    q = rng.integers(-30000, 30000, size=(5, 7, 3)).astype(np.int16)
    q[2:, 3] = -32768  # particle 3 leaves after snapshot 1
    q[4:, 0] = -32768
    mask, blob = encode_positions(q)
    np.testing.assert_array_equal(decode_positions(mask, blob, 5, 7), q)


@pytest.mark.solver
def test_pack_unpack_is_exact(hopper_tiny_dataset: Path, tmp_path: Path):
    parts = pack(hopper_tiny_dataset, tmp_path / "pack", max_part_mb=0.05)  # force several parts
    assert len(parts) > 1
    unpack(parts, tmp_path / "copy")
    orig, copy = Manifest.load(hopper_tiny_dataset), Manifest.load(tmp_path / "copy")
    assert copy.scene == orig.scene and copy.splits == orig.splits
    for rec in orig.usable():
        with HopperFile(hopper_tiny_dataset / rec.file) as a, HopperFile(tmp_path / "copy" / rec.file) as b:
            np.testing.assert_array_equal(a.positions(), b.positions())
            np.testing.assert_array_equal(a.exit_times, b.exit_times)
            np.testing.assert_array_equal(a.times, b.times)
            assert not b.has_velocities
            with pytest.raises(DataError, match="velocity is absent"):
                b.velocities()
    dm = HopperDataModule(str(tmp_path / "copy"), "hopper_tiny", ["t", "alpha"], n_queries=16)
    dm.setup()
    ref = HopperDataModule(str(hopper_tiny_dataset), "hopper_tiny", ["t", "alpha"], n_queries=16)
    ref.setup()
    assert dm.norm == ref.norm
    for key, value in dm.datasets["val"][3].items():
        np.testing.assert_array_equal(value.numpy(), ref.datasets["val"][3][key].numpy())
