"""The sampling floor of short CFD-DEM references: windows and their pooled statistics against the whole series,
checked with numpy on a real fb_tiny trajectory (20 snapshots from snapshot 1, windows of 5)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from neuraldem.errors import DataError
from neuraldem.scenes.fluidized_bed.analysis.reference_floor import main, measure, spread, windows
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile

pytestmark = pytest.mark.solver


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def test_spread_takes_the_first_last_and_evenly_between():
    assert spread(10, 3) == [0, 4, 9] or spread(10, 3) == [0, 5, 9]
    assert spread(4, 4) == [0, 1, 2, 3] and spread(7, 1) == [0]


def test_windows_and_the_pooled_floor_match_numpy(fb_tiny_dataset: Path):
    doc = measure(fb_tiny_dataset, window=5, pool=2, sims=("sim_0000",))
    (r,) = doc["trajectories"]
    with BedFile(fb_tiny_dataset / "sims" / "sim_0000.h5") as f:
        alpha = f.solid_fraction()[1:]  # from snapshot 1, as a rollout is compared
    assert r["snapshots"] == len(alpha) == 20 and r["n_windows"] == 4 and r["pooled_windows"] == [0, 3]
    whole_mean, whole_std = alpha.mean(0), alpha.std(0)
    for i, w in enumerate(np.split(alpha, 4)):
        assert r["single"][i]["solid_fraction_mean"] == pytest.approx(_rel(w.mean(0), whole_mean), rel=1e-12)
        assert r["single"][i]["solid_fraction_std"] == pytest.approx(_rel(w.std(0), whole_std), rel=1e-12)
    both = np.concatenate([alpha[0:5], alpha[15:20]])
    assert r["pooled"]["solid_fraction_mean"] == pytest.approx(_rel(both.mean(0), whole_mean), rel=1e-12)
    assert r["first_window"] == r["single"][0] and r["pooled"]["solid_fraction_mean"] > 0
    halves = _rel(alpha[:10].mean(0), alpha[10:].mean(0))  # the two halves, one against the other
    assert r["halves"]["solid_fraction_mean"] == pytest.approx(halves, rel=1e-12)
    assert r["perfect_model_estimate"]["solid_fraction_mean"] == pytest.approx(halves / np.sqrt(2), rel=1e-12)
    # all four windows pooled are the whole series: no error
    everything = measure(fb_tiny_dataset, window=5, pool=4, sims=("sim_0000",))["trajectories"][0]
    assert all(v == pytest.approx(0.0, abs=1e-12) for v in everything["pooled"].values())


def test_windows_drop_a_short_rest(fb_tiny_dataset: Path):
    from neuraldem.scenes.fluidized_bed.analysis.evaluation import FieldSeries

    with BedFile(fb_tiny_dataset / "sims" / "sim_0000.h5") as f:
        s = FieldSeries.from_dataset_file(f)
    parts = windows(s, 6)
    assert len(parts) == 3 and all(len(p.times) == 6 for p in parts) and parts[2].times[-1] == s.times[17]


def test_cli_writes_markdown_and_json_and_refuses_bad_input(fb_tiny_dataset: Path, tmp_path: Path, capsys):
    out = tmp_path / "floor.md"
    assert main([f"dataset={fb_tiny_dataset}", f"out={out}", "window=5", "sims=[sim_0000,sim_0002]"]) == 0
    saved = json.loads(out.with_suffix(".json").read_text())
    assert [r["sim_id"] for r in saved["trajectories"]] == ["sim_0000", "sim_0002"]
    assert "3 windows pooled" in out.read_text()
    with pytest.raises(DataError, match="no long trajectories"):  # fb_tiny has none
        measure(fb_tiny_dataset, window=5)
    with pytest.raises(DataError, match=r"sims=\[sim_0099\]: not finished"):
        measure(fb_tiny_dataset, window=5, sims=("sim_0099",))
    with pytest.raises(DataError, match="fewer than pool=9"):
        measure(fb_tiny_dataset, window=5, pool=9, sims=("sim_0000",))
    with pytest.raises(SystemExit) as stop:
        main([f"dataset={fb_tiny_dataset}", f"out={out}", "window=1", "sims=[sim_0000]"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "window=1 / pool=3: need a window" in err and len(err.strip().splitlines()) == 1


def test_a_long_validation_set_is_measured_with_its_tables_window(fb_tiny_dataset: Path, tmp_path: Path):
    """A set of long trajectories only (data=fb_small_longval: no training runs, long.part val) gives its long
    val trajectories and takes the window from its table's regular duration. Built from fb_tiny's real files with
    a relisted manifest (said so): sim_0002 as the long validation run, duration 0.05 s = 5 snapshots."""
    import shutil

    from neuraldem.data.manifest import Manifest

    ds = tmp_path / "longval"
    shutil.copytree(fb_tiny_dataset, ds, ignore=shutil.ignore_patterns("runs", "*.lock"))
    m = Manifest.load(ds)
    m.parameters = {**m.parameters, "n_velocities": 0, "duration": 0.05}
    m.splits = {"velocity": {"train": [], "val": [], "test": []},
                "long": {"train": [], "val": ["sim_0002"], "test": []}}
    m.save(ds)
    doc = measure(ds)
    assert doc["window"] == 5 and [r["sim_id"] for r in doc["trajectories"]] == ["sim_0002"]
    m.parameters["n_velocities"] = 3  # a regular table without finished training runs still needs window=
    m.save(ds)
    with pytest.raises(DataError, match="give window=SNAPSHOTS"):
        measure(ds)
