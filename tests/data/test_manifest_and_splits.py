"""Manifest persistence and splits: failed/clogged runs never enter a split; band split holds out a band."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from neuraldem.data.manifest import MANIFEST_NAME, Manifest, SimRecord, require_dataset
from neuraldem.data.splits import auto_theta_band, band_split, random_split
from neuraldem.errors import DataError


def records(n: int = 40, seed: int = 0) -> list[SimRecord]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        rec = SimRecord(sim_id=f"sim_{i:04d}", index=i, params={"alpha": float(rng.uniform(0, 60))},
                        macro={"theta": float(rng.uniform(10, 30))}, status="ok", file=f"sims/sim_{i:04d}.h5")
        out.append(rec)
    out[3].status, out[3].file = "failed", None
    out[5].status = "clogged"
    return out


def test_save_load_round_trip(tmp_path: Path):
    m = Manifest(name="t", kind="hopper", scene={"a": 1}, solver={"name": "LIGGGHTS", "version": "x"},
                 parameters={}, simulations=records(6))
    m.save(tmp_path)
    back = Manifest.load(tmp_path)
    assert back.simulations == m.simulations and back.scene == m.scene
    assert [r.sim_id for r in back.usable()] == ["sim_0000", "sim_0001", "sim_0002", "sim_0004"]


def test_require_dataset_messages(tmp_path: Path):
    with pytest.raises(DataError, match=r"no dataset at .*datagen data=hopper_tiny"):
        require_dataset(tmp_path, "hopper_tiny")
    (tmp_path / MANIFEST_NAME).write_text("{not json")
    with pytest.raises(DataError, match="not valid JSON"):
        require_dataset(tmp_path, "hopper_tiny")
    m = Manifest(name="t", kind="hopper", scene={}, solver={}, parameters={},
                 simulations=[SimRecord("sim_0000", 0, {})])
    m.save(tmp_path)
    with pytest.raises(DataError, match="no finished simulation"):
        require_dataset(tmp_path, "hopper_tiny")
    raw = json.loads((tmp_path / MANIFEST_NAME).read_text())
    raw["schema_version"] = 0
    (tmp_path / MANIFEST_NAME).write_text(json.dumps(raw))
    with pytest.raises(DataError, match="schema version 0"):
        Manifest.load(tmp_path)


def test_random_split_is_a_seeded_partition():
    ids = [f"s{i}" for i in range(50)]
    a = random_split(ids, {"train": 0.8, "val": 0.1, "test": 0.1}, seed=1)
    assert sorted(a["train"] + a["val"] + a["test"]) == sorted(ids)
    assert (len(a["train"]), len(a["val"]), len(a["test"])) == (40, 5, 5)
    assert a == random_split(list(reversed(ids)), {"train": 0.8, "val": 0.1, "test": 0.1}, seed=1)
    assert a != random_split(ids, {"train": 0.8, "val": 0.1, "test": 0.1}, seed=2)


def test_band_split_holds_out_the_band():
    recs = [r for r in records() if r.usable]
    band = band_split(recs, (20.0, 40.0), (15.0, 25.0), val_fraction=0.1, seed=0)
    test = {r.sim_id for r in recs if 20 <= r.params["alpha"] <= 40 and 15 <= r.macro["theta"] <= 25}
    assert set(band["test"]) == test and test
    for rid in band["train"] + band["val"]:
        assert rid not in test
    assert sorted(band["train"] + band["val"] + band["test"]) == sorted(r.sim_id for r in recs)


def test_auto_theta_band_has_the_alpha_bands_relative_width():
    lo, hi = auto_theta_band(np.array([10.0, 30.0]), (20.0, 40.0), (0.0, 60.0))
    assert (lo, hi) == pytest.approx((10 + 20 / 3, 30 - 20 / 3))
