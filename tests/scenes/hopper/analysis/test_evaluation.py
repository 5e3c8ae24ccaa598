"""The evaluation path: DEM data through it reproduces the ground-truth metrics exactly; a wrong checkpoint
or a wrong scene is refused with a clear message."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from neuraldem.data.manifest import Manifest
from neuraldem.errors import DataError
from neuraldem.scenes.hopper.analysis.evaluation import load_hopper_checkpoint
from neuraldem.scenes.hopper.analysis.scoring import SCALARS, aggregate, dataset_metric_settings, evaluate_sims
from neuraldem.scenes.hopper.dataset.store import HopperFile
from neuraldem.scenes.hopper.surrogate.predictors import DemPredictor, time_grid
from tests.helpers import rerecord_checksum

pytestmark = pytest.mark.solver


def test_dem_through_the_prediction_path_reproduces_ground_truth(hopper_tiny_dataset: Path):
    m = Manifest.load(hopper_tiny_dataset)
    hop = m.scene["hopper"]
    settings = dataset_metric_settings(m)
    assert m.metric_settings == settings.as_dict()  # datagen recorded what it scored with
    radius = settings.occupancy_radius_d * hop["material"]["diameter"]
    horizon = hop["max_time"]  # the metrics' time range: runs that ended earlier hold their final state
    assert max(r.metrics["duration"] for r in m.usable()) < horizon  # so the held state is exercised
    dem = DemPredictor(hopper_tiny_dataset, radius, horizon=horizon)
    times = time_grid(horizon, hop["snapshot_interval"])
    evals = evaluate_sims(m.usable(), hopper_tiny_dataset, dem, dem, times, np.ones(3), horizon, settings,
                          progress=False)
    for e, rec in zip(evals, m.usable(), strict=False):
        for key in (*SCALARS, "mass_flow", "residual_fraction_particles"):
            np.testing.assert_equal(e.predicted.get(key, e.truth[key]), e.truth[key])
            np.testing.assert_equal(e.truth[key], rec.metrics[key])  # == datagen's numbers (nan == nan)
        assert e.transport_mse == 0.0 and e.residence_mse == 0.0
    agg = aggregate(evals)
    assert agg["drainage_t95_pct_of_mean"] == 0.0 and agg["residual_mae_pp"] == 0.0
    assert agg["outflow_rel_err_pct"] == 0.0 and agg["flow_regime_accuracy"] == 1.0


def test_not_a_checkpoint(tmp_path: Path):
    bad = tmp_path / "x.ckpt"
    bad.write_text("hello")
    with pytest.raises(DataError, match="not a readable checkpoint"):
        load_hopper_checkpoint(bad)
    torch.save({"state_dict": {}}, bad)
    with pytest.raises(DataError, match="not a neuraldem checkpoint"):
        load_hopper_checkpoint(bad)
    torch.save({"hyper_parameters": {"metadata": {"kind": "fluidized_bed"}}}, bad)
    with pytest.raises(DataError, match="'fluidized_bed' checkpoint"):
        load_hopper_checkpoint(bad)


def test_query_points_are_real_initial_positions(hopper_tiny_dataset: Path):
    m = Manifest.load(hopper_tiny_dataset)
    with HopperFile(hopper_tiny_dataset / m.usable()[0].file) as f:
        assert np.isfinite(f.initial_positions()).all()


def test_checkpoint_on_another_scene_is_refused(tiny_checkpoint: Path, hopper_tiny_dataset: Path, tmp_path: Path):
    import shutil

    from neuraldem.scenes.hopper.analysis.evaluation import evaluate_checkpoint

    other = tmp_path / "other"
    shutil.copytree(hopper_tiny_dataset, other)
    m = Manifest.load(other)
    m.scene["hopper"]["n_particles"] = 400
    m.save(other)
    with pytest.raises(DataError, match=r"scene differs .*\['hopper\.n_particles'\]"):
        evaluate_checkpoint(tiny_checkpoint, tmp_path / "out", tmp_path, dataset_dir=other, progress=False)


def test_evaluate_writes_everything(tiny_checkpoint: Path, hopper_tiny_dataset: Path, tmp_path: Path):
    from neuraldem.scenes.hopper.analysis.evaluation import evaluate_checkpoint

    result = evaluate_checkpoint(tiny_checkpoint, tmp_path, tmp_path, dataset_dir=hopper_tiny_dataset,
                                 part="val", progress=False)
    assert result["aggregate"]["n_sims"] >= 1 and "command" in result and result["machine"]["cpu_count"]
    # the baselines, fitted on the model's own training runs, scored on the same runs, in the same table
    assert set(result["baselines"]) == {"constant", "gp"}
    assert result["baselines"]["gp"]["aggregate"]["n_sims"] == result["aggregate"]["n_sims"]
    assert [row.split("|")[1].strip() for row in result["table_rows"]] == ["field model", "constant", "gp"]
    for name in ("metrics.json", "table.md", "predicted_vs_dem.png", "stripes.png", "residence_slice.png"):
        assert (tmp_path / name).is_file()
    pvd = next((tmp_path / "vtk").glob("*.pvd"))
    import meshio

    first = next((tmp_path / "vtk").glob("*_0000.vtu"))
    mesh = meshio.read(first)
    assert {"transport_layer", "residence_time", "occupancy"} <= set(mesh.point_data)
    assert "<Collection>" in pvd.read_text()


def test_outside_the_trained_ranges_is_answered_and_flagged(tiny_checkpoint: Path, hopper_tiny_dataset: Path,
                                                            tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    """A run whose friction lies outside what the model was trained on still gets an answer, flagged as an
    extrapolation (in metrics.json, the aggregate's count and a warning naming the scalar and the range)."""
    import shutil

    from neuraldem.scenes.hopper.analysis.evaluation import evaluate_checkpoint

    other = tmp_path / "other"
    shutil.copytree(hopper_tiny_dataset, other)
    m = Manifest.load(other)
    meta = torch.load(tiny_checkpoint, map_location="cpu", weights_only=False)["hyper_parameters"]["metadata"]
    val_id = meta["split_ids"]["val"][0]
    m.record(val_id).params["mu_s"] = 5.0
    m.save(other)
    result = evaluate_checkpoint(tiny_checkpoint, tmp_path / "out", tmp_path, dataset_dir=other, part="val",
                                 vtk=False, progress=False)
    flagged = {s["sim_id"]: s["extrapolation"] for s in result["simulations"]}
    assert flagged[val_id]["mu_s"][0] == 5.0 and result["aggregate"]["n_extrapolated"] >= 1
    assert np.isfinite(result["aggregate"]["drainage_t95_pct_of_mean"])  # answered all the same
    assert f"{val_id}: extrapolation, outside the trained range: mu_s=5" in capsys.readouterr().err


def test_a_run_outside_the_trained_box_is_flagged_and_the_others_evaluated(
        tiny_checkpoint: Path, hopper_tiny_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    """Query points far outside the box the model learned cannot be answered: that run is named (metrics.json,
    a warning) and left out, the other runs are scored; when no run is inside, one clear error."""
    import shutil

    import h5py

    from neuraldem.scenes.hopper.analysis.evaluation import evaluate_checkpoint

    other = tmp_path / "other"
    shutil.copytree(hopper_tiny_dataset, other)
    m = Manifest.load(other)
    meta = torch.load(tiny_checkpoint, map_location="cpu", weights_only=False)["hyper_parameters"]["metadata"]
    moved, kept = meta["split_ids"]["train"][:2]
    with h5py.File(other / str(m.record(moved).file), "r+") as f:  # the whole run 1 m higher than any trained
        f["snapshots/position"].attrs["origin"] = f["snapshots/position"].attrs["origin"] + [0.0, 0.0, 1.0]
    rerecord_checksum(other, other / str(m.record(moved).file))
    result = evaluate_checkpoint(tiny_checkpoint, tmp_path / "out", tmp_path, dataset_dir=other, part="train",
                                 max_sims=2, vtk=False, progress=False)
    assert [s["sim_id"] for s in result["simulations"]] == [kept] and result["aggregate"]["n_sims"] == 1
    assert [s["sim_id"] for s in result["skipped"]] == [moved] and "outside the scene box" in result["skipped"][0][
        "reason"]
    assert json.loads((tmp_path / "out" / "metrics.json").read_text())["skipped"][0]["sim_id"] == moved
    assert f"warning: {moved} not evaluated" in capsys.readouterr().err
    with pytest.raises(DataError, match="none of the 1 runs .* lies inside the box"):
        evaluate_checkpoint(tiny_checkpoint, tmp_path / "out2", tmp_path, dataset_dir=other, part="train",
                            max_sims=1, vtk=False, progress=False)


def test_dem_fields_on_every_second_time_are_the_full_grid_subsampled(hopper_tiny_dataset: Path):
    """The validation callback asks DEM for every 2nd time: each time must get its own snapshot (a subsampled
    grid was once paired with the first snapshots in order)."""
    m = Manifest.load(hopper_tiny_dataset)
    rec = max(m.usable(), key=lambda r: r.metrics["duration"])
    hop = m.scene["hopper"]
    dem = DemPredictor(hopper_tiny_dataset, 0.6 * hop["material"]["diameter"], horizon=hop["max_time"])
    times = time_grid(hop["max_time"], hop["snapshot_interval"])
    with HopperFile(hopper_tiny_dataset / rec.file) as f:
        points = f.initial_positions()[::7]
    full, half = dem.fields(rec, times, points), dem.fields(rec, times[::2], points)
    np.testing.assert_array_equal(half.occupancy, full.occupancy[::2])
    assert full.occupancy[0].all() and full.occupancy.sum(1)[-1] < full.occupancy.sum(1)[0]
    with pytest.raises(DataError, match="not on its snapshot grid"):
        dem.fields(rec, times[:3] + 0.01, points)
