"""Fluidized-bed baselines from the training trajectories: the interpolation weights, a trajectory scored
against itself, the layout the run table reads, and the refusals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from neuraldem.errors import DataError
from neuraldem.scenes.fluidized_bed.analysis import table as collect_fb_table
from neuraldem.scenes.fluidized_bed.analysis.baselines import blend, bracket, evaluate_baselines
from neuraldem.scenes.fluidized_bed.analysis.evaluation import FieldSeries
from neuraldem.sim.foam_reader import BoxGrid


def _series(value: float, n: int = 4) -> FieldSeries:
    """Synthetic constant fields (unit test of the arithmetic, not solver data)."""
    grid = BoxGrid(lo=(0.0, 0.0, 0.0), hi=(1.0, 1.0, 1.0), shape=(2, 1, 2))
    shape = (n, 2, 1, 2)
    return FieldSeries(np.arange(n, dtype=float), np.full(shape, value), np.full(shape + (3,), value),
                       np.full(shape, value), grid, 1e-6, 1e-3)


def test_bracket_weights_are_linear_in_velocity_and_the_nearest_outside_the_range():
    train = [(1.0, _series(0.1)), (2.0, _series(0.3)), (3.0, _series(0.5))]
    runs, weights = bracket(train, 1.25)
    assert [r.solid_fraction[0, 0, 0, 0] for r in runs] == [0.1, 0.3]
    assert weights == pytest.approx([0.75, 0.25])
    assert blend(runs, weights).solid_fraction == pytest.approx(np.full((4, 2, 1, 2), 0.15))
    runs, weights = bracket(train, 3.7)  # beyond the training range: the nearest run alone
    assert weights == [1.0] and runs[0].solid_fraction[0, 0, 0, 0] == 0.5
    runs, weights = bracket(train, 2.0)  # on a training velocity: that run
    assert weights == [1.0] and runs[0].solid_fraction[0, 0, 0, 0] == 0.3


def test_blend_keeps_the_snapshots_all_runs_have():
    assert len(blend([_series(0.1, 4), _series(0.3, 6)], [0.5, 0.5]).times) == 4


@pytest.mark.solver
def test_a_training_trajectory_scored_against_itself_and_the_table(fb_tiny_dataset: Path, tmp_path: Path):
    docs = evaluate_baselines(fb_tiny_dataset, tmp_path, part="train")
    near = docs["nearest"]["trajectories"][0]
    assert near["sim_id"] == "sim_0000"  # its own nearest training run: every statistic agrees exactly
    assert all(v == 0.0 for v in near["rel_l2"].values()), near["rel_l2"]
    assert near["lacey"]["mae"] == 0.0 and not near["extrapolation"]
    const = docs["constant"]["trajectories"][0]  # the mean of two packings differs from either
    assert const["rel_l2"]["solid_fraction_std"] > 0.0
    for b in ("nearest", "interpolated", "constant"):
        saved = json.loads((tmp_path / f"baseline_{b}" / "evaluation" / "metrics.json").read_text())
        assert saved["baseline"] == b and saved["training"]["parameters"] == 0
    table = collect_fb_table.render(collect_fb_table.fb_results([tmp_path]))
    assert "CFD-DEM at the nearest training velocity" in table and "baseline_constant" in table


@pytest.mark.solver
def test_bad_input_names_the_fix(fb_tiny_dataset: Path, tmp_path: Path):
    with pytest.raises(DataError, match="unknown fluidized-bed baseline 'gp'"):
        evaluate_baselines(fb_tiny_dataset, tmp_path, baselines=("gp",))
    with pytest.raises(DataError, match="no finished val trajectories"):
        evaluate_baselines(fb_tiny_dataset, tmp_path, part="val")
    with pytest.raises(DataError, match=r"exclude=\[sim_0002\]: not training trajectories"):
        evaluate_baselines(fb_tiny_dataset, tmp_path, exclude=("sim_0002",))
    with pytest.raises(DataError, match=r"only=\[sim_0000\]: not test trajectories"):
        evaluate_baselines(fb_tiny_dataset, tmp_path, only=("sim_0000",))


@pytest.mark.solver
def test_only_scores_the_named_held_out_trajectories(fb_tiny_dataset: Path, tmp_path: Path):
    """By default one trajectory per velocity (the first by id); only=[sim_0001] scores the second packing."""
    docs = evaluate_baselines(fb_tiny_dataset, tmp_path, part="train", baselines=("constant",), only=("sim_0001",))
    assert [t["sim_id"] for t in docs["constant"]["trajectories"]] == ["sim_0001"]


@pytest.mark.solver
def test_excluded_runs_are_not_used(fb_tiny_dataset: Path, tmp_path: Path):
    docs = evaluate_baselines(fb_tiny_dataset, tmp_path, part="train", exclude=("sim_0000",))
    near = docs["nearest"]["trajectories"][0]  # sim_0000 scored against the other packing, not itself
    assert near["sim_id"] == "sim_0000" and near["rel_l2"]["solid_fraction_mean"] > 0.0
    assert docs["nearest"]["excluded"] == ["sim_0000"]


@pytest.mark.solver
def test_the_other_packing_is_the_seed_spread_where_a_twin_exists(fb_tiny_dataset: Path, tmp_path: Path):
    """fb_tiny holds two packings of its low (training) velocity and one of its high (test) one: the twin of
    sim_0000 is the other packing (the same answer as the nearest training run once sim_0000 itself is left
    out), and the test velocity, with no twin, is not scored."""
    twin = evaluate_baselines(fb_tiny_dataset, tmp_path / "twin", part="train",
                              baselines=("other_packing",))["other_packing"]
    near = evaluate_baselines(fb_tiny_dataset, tmp_path / "near", part="train", exclude=("sim_0000",),
                              baselines=("nearest",))["nearest"]
    assert [t["sim_id"] for t in twin["trajectories"]] == ["sim_0000"]
    assert twin["trajectories"][0]["rel_l2"] == near["trajectories"][0]["rel_l2"]
    # the replayed twin is left out of the pooled reference (a run compared with itself would score 0)
    assert twin["trajectories"][0]["pooled"]["sims"] == ["sim_0000"]
    assert twin["trajectories"][0]["pooled"]["rel_l2"] == twin["trajectories"][0]["rel_l2_full"]
    assert near["trajectories"][0]["pooled"]["sims"] == ["sim_0000", "sim_0001"]
    assert twin["trajectories"][0]["rel_l2"]["solid_fraction_mean"] > 0.0
    alone = evaluate_baselines(fb_tiny_dataset, tmp_path / "test", part="test", baselines=("nearest", "other_packing"))
    assert set(alone) == {"nearest"} and not (tmp_path / "test" / "baseline_other_packing").exists()


def test_baselines_of_a_long_validation_set_come_from_the_training_dataset(fb_tiny_dataset: Path, tmp_path: Path):
    """A set of long trajectories only (like fb_small_longval) has no training runs: `train_dir` takes them, and the
    other packings at its velocity, from the dataset the models trained on. Built from fb_tiny's real files with a
    relisted manifest (said so): sim_0001 (1.23 m/s) as the long set's one run, listed in its part."""
    import shutil

    from neuraldem.data.manifest import Manifest
    from neuraldem.errors import DataError

    lv = tmp_path / "longval"
    shutil.copytree(fb_tiny_dataset, lv, ignore=shutil.ignore_patterns("runs", "*.lock"))
    m = Manifest.load(lv)
    m.simulations = [r for r in m.simulations if r.sim_id == "sim_0001"]
    m.splits = {"velocity": {"train": [], "val": [], "test": []},
                "long": {"train": ["sim_0001"], "val": [], "test": []}}
    m.save(lv)
    with pytest.raises(DataError, match="no finished training trajectories"):  # none of its own
        evaluate_baselines(lv, tmp_path / "own", part="train")
    docs = evaluate_baselines(lv, tmp_path / "b", part="train", baselines=("nearest", "other_packing"),
                              train_dir=fb_tiny_dataset)
    near, twin = docs["nearest"], docs["other_packing"]
    assert near["training_dataset"] == str(fb_tiny_dataset) and near["training_velocities"] == pytest.approx(
        [1.228531, 1.228531])
    # the other packing is fb_tiny's sim_0000 (a run of another dataset, so the pooled reference keeps lv's run)
    assert twin["trajectories"][0]["rel_l2"] == near["trajectories"][0]["rel_l2"]
    assert twin["trajectories"][0]["pooled"]["sims"] == ["sim_0001"]
    assert twin["trajectories"][0]["rel_l2"]["solid_fraction_mean"] > 0.0
    m.scene = {**m.scene, "fluidized_bed": {**m.scene["fluidized_bed"], "n_particles": 7}}
    m.save(lv)
    with pytest.raises(DataError, match="scene differs"):
        evaluate_baselines(lv, tmp_path / "c", part="train", train_dir=fb_tiny_dataset)
