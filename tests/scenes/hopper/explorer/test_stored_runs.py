"""Stored LIGGGHTS runs near the explored point: found in the model's own dataset, near means within a share
of each trained range, and no dataset (or another scene's) leaves the overlay off with a line that says why."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from neuraldem.scenes.hopper.explorer.stored_runs import StoredRuns
from tests.conftest import TINY


@pytest.fixture(scope="module")
def tiny_meta(tiny_pretrained: Path) -> dict:
    return json.loads((tiny_pretrained / TINY / "meta.json").read_text())


def test_a_run_at_the_point_is_near_and_readable(tiny_meta: dict, hopper_tiny_dataset: Path):
    stored, note = StoredRuns.for_model(tiny_meta, hopper_tiny_dataset)
    assert stored is not None and "stored LIGGGHTS runs at" in note
    rec = next(iter(stored.records.values()))
    near = stored.nearest(dict(rec.params))
    assert near is not None and near.sim_id == rec.sim_id and near.distance == 0
    assert near.metrics["drainage_t95"] == rec.metrics["drainage_t95"] and rec.sim_id in near.label()
    t, positions = stored.particles(rec.sim_id, 0.0)
    assert t == 0 and positions.shape[1] == 3 and np.isfinite(positions).all()
    assert len(stored.particles(rec.sim_id, 0.0, limit=50)[1]) == 50
    left = stored.remaining(rec.sim_id, np.array([0.0, 1.0, 5.0]))
    assert left[0] == 1.0 and np.all(np.diff(left) <= 0)


def test_near_means_within_a_share_of_each_trained_range(tiny_meta: dict, hopper_tiny_dataset: Path):
    stored, _ = StoredRuns.for_model(tiny_meta, hopper_tiny_dataset, near=0.05)
    rec = next(iter(stored.records.values()))
    lo, hi = tiny_meta["trained_range"]["alpha"]
    inside = {**rec.params, "alpha": rec.params["alpha"] + 0.04 * (hi - lo)}
    found = stored.nearest(inside)
    assert found is not None and found.distance <= 0.04 + 1e-9
    assert stored.nearest({"alpha": 1e3, "mu_s": 0.5, "mu_r": 0.2}) is None


def test_no_dataset_leaves_the_overlay_off(tiny_meta: dict, tmp_path: Path):
    stored, note = StoredRuns.for_model(tiny_meta, tmp_path / "nothing")
    assert stored is None and note == f"overlay off: no stored LIGGGHTS runs at {tmp_path / 'nothing'}"


def test_runs_of_another_scene_are_not_shown(tiny_meta: dict, hopper_tiny_dataset: Path, tmp_path: Path):
    other = tmp_path / "other"
    other.mkdir()
    manifest = json.loads((hopper_tiny_dataset / "manifest.json").read_text())
    manifest["scene"]["hopper"]["n_particles"] += 1
    (other / "manifest.json").write_text(json.dumps(manifest))
    shutil.copytree(hopper_tiny_dataset / "sims", other / "sims")
    stored, note = StoredRuns.for_model(tiny_meta, other)
    assert stored is None and "another hopper scene" in note
