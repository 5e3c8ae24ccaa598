"""Fluidized-bed evaluation: ground truth fed through the rollout/evaluation path reproduces its own metrics,
a model's evaluation writes its report, and the stability report counts steps until divergence."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from neuraldem.data.manifest import Manifest
from neuraldem.scenes.fluidized_bed.analysis import metrics as fm
from neuraldem.scenes.fluidized_bed.analysis.evaluation import (
    FieldSeries,
    compare,
    compare_pooled,
    curves,
    evaluate_checkpoint,
    evaluate_trajectory,
    held_out,
    pooled_reference,
)
from neuraldem.scenes.fluidized_bed.dataset.report import metric_settings
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.rollout import DataStepper, ModelStepper
from tests.helpers import run_module
from tests.scenes.fluidized_bed.surrogate.test_rollout import Inject, _nan

pytestmark = pytest.mark.solver


@pytest.mark.parametrize(("sim", "via_file"), [("sim_0000", True), ("sim_0002", True), ("sim_0002", False)])
def test_ground_truth_through_the_prediction_path_gives_its_own_metrics(fb_tiny_dataset: Path, tmp_path: Path,
                                                                        sim: str, via_file: bool):
    m = Manifest.load(fb_tiny_dataset)
    rec, settings = m.record(sim), metric_settings(m)
    path = fb_tiny_dataset / str(rec.file)
    with BedFile(path) as f:
        steps, truth_alpha = f.n_snapshots - 1, f.solid_fraction()
        truth_volume = fm.total_solid_volume(truth_alpha, f.grid.cell_volume)
        e = evaluate_trajectory(path, sim, rec.params["inlet_velocity"], DataStepper(f), steps, horizon_steps=steps,
                                horizons=[1, 3], settings=settings,
                                rollout_path=tmp_path / "gt.h5" if via_file else None, init_snapshot=0)
    r = e.result
    assert r["window_steps"] == steps and set(r["rel_l2"]) >= {"solid_fraction_mean", "fluid_speed_std"}
    assert all(v == 0.0 for v in r["rel_l2"].values()), r["rel_l2"]
    assert all(v == 0.0 for v in r["rel_l2_full"].values()), r["rel_l2_full"]
    assert r["lacey"]["mae"] == 0.0
    assert r["mass"] == r["mass_truth"]
    assert r["mass"]["drift_pct"] == 100 * (truth_volume[-1] / truth_volume[0] - 1)
    assert r["mass"]["max_drift_pct"] == 100 * fm.mass_conservation_error(truth_volume)
    # the scalar metrics equal the ones datagen stored in the manifest for this trajectory
    for key, value in r["summary_pred"].items():
        stored = rec.metrics[key]
        assert (math.isnan(value) and math.isnan(stored)) or value == stored, (key, value, stored)
    assert r["bed_height"]["mean_pred"] == r["bed_height"]["mean_truth"] == rec.metrics["bed_height_mean"]
    assert np.array_equal(e.pred.solid_fraction, truth_alpha)
    lr = r["structure"]  # the same fields: no error, the rollout's asymmetry and lean are CFD-DEM's
    assert lr["mean_profile_rel_l2"] == lr["mean_lateral_rel_l2"] == 0.0
    assert lr["mean_asymmetry_pred"] == lr["mean_asymmetry_truth"] > 0 and lr["std_lean_pred"] == lr["std_lean_truth"]
    assert r["stability"]["steps_to_divergence"] is None
    assert [h["stable"] for h in r["stability"]["horizons"]] == [True, False]  # 3x is beyond the data


def test_pooled_reference_holds_every_packing_of_the_velocity_together(fb_tiny_dataset: Path):
    """Known answers: the per-cell statistics over both packings' snapshots (numpy on the concatenation), the
    Lacey MAE against the mean of the two curves, zero against the run itself alone."""
    m = Manifest.load(fb_tiny_dataset)
    settings = metric_settings(m)
    ids, series = pooled_reference(m, fb_tiny_dataset, m.record("sim_0000"), 0)
    assert ids == ["sim_0000", "sim_0001"]
    alpha = np.concatenate([s.solid_fraction for s in series])
    q = compare_pooled(series[0], series, settings, ids)
    mean0, mean_all = series[0].solid_fraction.mean(0), alpha.mean(0)
    std0, std_all = series[0].solid_fraction.std(0), alpha.std(0)
    assert q["rel_l2"]["solid_fraction_mean"] == pytest.approx(np.linalg.norm(mean0 - mean_all)
                                                               / np.linalg.norm(mean_all), rel=1e-12)
    assert q["rel_l2"]["solid_fraction_std"] == pytest.approx(np.linalg.norm(std0 - std_all)
                                                              / np.linalg.norm(std_all), rel=1e-12)
    assert q["rel_l2"]["solid_fraction_mean"] > 0 and q["snapshots"] == len(alpha)
    l0, l1 = (curves(s, settings)["lacey_field"] for s in series)
    half_gap = np.abs(l0 - l1) / 2  # |L0 - (L0 + L1) / 2|
    assert q["lacey_mae"] == pytest.approx(float(np.nanmean(half_gap)), rel=1e-12) and q["lacey_mae"] > 0
    alone = compare_pooled(series[0], series[:1], settings, ids[:1])
    assert all(v == 0.0 for v in alone["rel_l2"].values()) and alone["lacey_mae"] == 0.0
    rest, _ = pooled_reference(m, fb_tiny_dataset, m.record("sim_0000"), 0, leave_out="sim_0000")
    assert rest == ["sim_0001"]
    single, _ = pooled_reference(m, fb_tiny_dataset, m.record("sim_0002"), 0)  # the test velocity: one run
    assert single == ["sim_0002"]


def test_a_mirrored_bed_is_scored_as_all_lateral_error_with_the_lean_reversed(fb_tiny_dataset: Path):
    """Known answer on real CFD-DEM fields: the bed's mirror image in x has the same height profile (all of its
    time-mean error is lateral), the same asymmetry and the opposite lean."""
    m = Manifest.load(fb_tiny_dataset)
    with BedFile(fb_tiny_dataset / str(m.record("sim_0000").file)) as f:
        truth = FieldSeries.from_dataset_file(f)
    mirrored = FieldSeries(truth.times, truth.solid_fraction[:, ::-1], truth.fluid_velocity[:, ::-1],
                           truth.mixing[:, ::-1], truth.grid, truth.particle_volume, truth.total_particle_volume)
    r = compare(mirrored, truth, metric_settings(m))
    lr = r["structure"]
    assert r["rel_l2"]["solid_fraction_mean"] > 0.01
    assert lr["mean_profile_rel_l2"] == pytest.approx(0.0, abs=1e-12)
    assert lr["mean_lateral_rel_l2"] == pytest.approx(r["rel_l2"]["solid_fraction_mean"], rel=1e-12)
    assert lr["mean_asymmetry_pred"] == pytest.approx(lr["mean_asymmetry_truth"], rel=1e-12)
    assert lr["std_lean_pred"] == pytest.approx(-lr["std_lean_truth"], rel=1e-12) and lr["std_lean_truth"] != 0
    assert lr["std_wall_share_pred"] == pytest.approx(lr["std_wall_share_truth"], rel=1e-12)  # both walls


def test_evaluation_of_a_model_writes_metrics_report_and_plots(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path,
                                                               tmp_path: Path):
    env = {"NEURALDEM_DATA": str(fb_tiny_dataset.parent.parent)}
    proc = run_module("neuraldem.evaluate", f"ckpt={fb_tiny_checkpoint}", "fluidized_bed.horizons=[1,3]",
                      f"hydra.run.dir={tmp_path}", env=env)
    assert proc.returncode == 0, proc.stderr
    assert "Fluidized-bed surrogate vs CFD-DEM" in proc.stdout and "held-out velocities" in proc.stdout
    train = run_module("neuraldem.evaluate", f"ckpt={fb_tiny_checkpoint}", "fluidized_bed.horizons=[1]", "part=train",
                       "vtk=false", "rollout.mirror_alternate=true", f"hydra.run.dir={tmp_path}/train", env=env)
    assert train.returncode == 0 and "train trajectories:" in train.stdout, train.stderr  # not called held-out
    alternated = json.loads((tmp_path / "train" / "metrics.json").read_text())  # the override is recorded
    assert alternated["stability"]["mirror_alternate"] is True
    assert all(x["mirror_alternate"] is True for x in alternated["trajectories"])
    # the pooled reference of the training velocity: both of its packings, from snapshot 1 on (20 + 20)
    pooled = alternated["trajectories"][0]["pooled"]
    assert pooled["sims"] == ["sim_0000", "sim_0001"] and pooled["snapshots"] == 40
    assert pooled["pred_snapshots"] == 21 and pooled["rel_l2"]["solid_fraction_mean"] > 0
    assert alternated["aggregate"]["pooled_solid_fraction_std_rel_l2"] == pooled["rel_l2"]["solid_fraction_std"]
    result = json.loads((tmp_path / "metrics.json").read_text())
    assert result["training_horizon_steps"] == 20 and result["rollout_steps"] == 60
    (t,) = result["trajectories"]  # fb_tiny holds out one velocity
    assert t["sim_id"] == "sim_0002" and t["extrapolation"] is True  # 2.04 m/s, trained on 1.23 only
    assert result["init_snapshot"] == 1 and t["initial_state"].endswith("snapshot 1")
    assert t["window_steps"] == 19 and t["mass"]["steps"] == 60  # CFD-DEM has 19 steps after snapshot 1
    assert [(h["multiple"], h["steps"]) for h in t["stability"]["horizons"]] == [(1, 20), (3, 60)]
    assert 0 < t["rel_l2"]["solid_fraction_mean"] < 10 and math.isfinite(t["mass"]["drift_pct"])
    assert t["rel_l2_full"]["solid_fraction_mean"] != t["rel_l2"]["solid_fraction_mean"]  # 60 vs 20 steps
    assert result["aggregate"]["n_trajectories"] == 1 and result["aggregate"]["n_extrapolation"] == 1
    # one CFD-DEM run at the test velocity: the pooled reference is that run, whole rollout against it all
    assert t["pooled"]["sims"] == ["sim_0002"] and t["pooled"]["rel_l2"] == t["rel_l2_full"]
    report = (tmp_path / "report.md").read_text()
    assert "## Against every CFD-DEM trajectory at the velocity (pooled)" in report
    assert "## Left-right structure of the solid fraction" in report and "| 2.042 | pooled |" in report
    assert "| 2.042 | yes | 19 |" in report and "## Stability" in report and "3x (60 steps)" in report
    for name in ("time_averages_sim_0002.png", "curves_sim_0002.png", "lateral_profiles_sim_0002.png",
                 "solid_volume.png", "rollouts/sim_0002.h5",
                 "vtk/sim_0002_grid.pvd"):
        assert (tmp_path / name).is_file(), name


def test_stability_report_counts_steps_until_divergence(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path,
                                                        tmp_path: Path):
    def stepper(module, velocity):
        return Inject(ModelStepper(module, velocity), at=30, spoil=_nan)

    with pytest.warns(UserWarning, match="outside the range"):
        result = evaluate_checkpoint(fb_tiny_checkpoint, tmp_path, fb_tiny_dataset.parent, horizons=[1, 3, 10],
                                     vtk=False, progress=False, make_stepper=stepper)
    (t,) = result["trajectories"]
    s = t["stability"]
    assert s["steps_to_divergence"] == 30 and s["steps_done"] == 29 and "NaN" in s["divergence"]
    assert [(h["steps"], h["stable"]) for h in s["horizons"]] == [(20, True), (60, False), (200, False)]
    assert t["mass"]["steps"] == 29
    agg = result["aggregate"]
    assert (agg["stable_at_1x"], agg["stable_at_3x"], agg["stable_at_10x"]) == (1, 0, 0)
    assert "| 2.042 | 30 (NaN/inf in the predicted fluid velocity (1 values)) | stable | diverged | diverged |" in \
        (tmp_path / "report.md").read_text()


def test_long_validation_trajectories_of_another_dataset_are_scored_as_val(fb_tiny_checkpoint: Path,
                                                                            fb_tiny_dataset: Path, tmp_path: Path):
    """A dataset of long validation trajectories (data.parameters.long.part=val, e.g. fb_small_longval) is scored
    with `evaluate dataset_dir=... part=val`, as `report fb-select --long-val` does. Built here from fb_tiny's real
    files, its manifest relisted: sim_0002 (2.04 m/s) as the one long validation trajectory (said so: it is 0.2 s)."""
    longval = tmp_path / "fb_tiny_longval"
    shutil.copytree(fb_tiny_dataset, longval, ignore=shutil.ignore_patterns("runs", "*.lock"))
    m = Manifest.load(longval)
    m.splits = {"velocity": {"train": [], "val": [], "test": []},
                "long": {"train": [], "val": ["sim_0002"], "test": []}}
    m.save(longval)
    assert [r.sim_id for r in held_out(m, "velocity", "val", None)] == ["sim_0002"]
    assert held_out(m, "velocity", "test", None) == []  # a validation trajectory is never a test one
    env = {"NEURALDEM_DATA": str(fb_tiny_dataset.parent.parent)}
    proc = run_module("neuraldem.evaluate", f"ckpt={fb_tiny_checkpoint}", f"dataset_dir={longval}", "part=val",
                      "fluidized_bed.horizons=[1]", "vtk=false", f"hydra.run.dir={tmp_path / 'eval'}", env=env)
    assert proc.returncode == 0, proc.stderr
    result = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert [t["sim_id"] for t in result["trajectories"]] == ["sim_0002"] and result["part"] == "val"
    assert result["dataset"] == str(longval)  # pooled against that dataset's runs at the velocity
    assert result["trajectories"][0]["pooled"]["sims"] == ["sim_0002"]
