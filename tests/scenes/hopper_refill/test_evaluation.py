"""Refill evaluation on the real tiny refill dataset: the reset rollout's aggregated residence equals the
particles' own residence, and a (3-step, untrained) model goes through the whole scoring path."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from neuraldem.data.manifest import Manifest
from neuraldem.errors import DataError
from neuraldem.scenes.hopper_refill.evaluation import PersistenceRefillQuery, dem_query, evaluate_refill_checkpoint
from neuraldem.scenes.hopper_refill.store import RefillFile
from neuraldem.scenes.hopper_refill.targets import aggregated_residence, reset_times

pytestmark = pytest.mark.solver


def test_aggregation_across_resets_equals_direct_residence_on_liggghts_data(hopper_refill_tiny_dataset: Path):
    m = Manifest.load(hopper_refill_tiny_dataset)
    rec = m.usable()[0]
    with RefillFile(hopper_refill_tiny_dataset / str(rec.file)) as f:
        resets = reset_times(0.0, float(f.times[-1]), 0.1)  # a reset every 2 snapshots
        query = dem_query(f, resets, radius=0.006)
        fill_age = -float(f.insert_times.min())  # the fill's residence at the opening (all inserted together)
        for k in (len(f.times) - 1, len(f.times) - 7):
            t = float(f.times[k])
            rows, pos = f.frame(k)
            agg = aggregated_residence(query, resets, t, pos, initial=lambda p: np.full(len(p), fill_age),
                                       new_tolerance=0.025)
            direct = t - f.insert_times[rows]
            assert (direct > 0.2).sum() > 20  # material older than two windows is in the hopper
            np.testing.assert_allclose(agg, direct, atol=1e-6)


def test_persistence_answer_is_exact_at_the_reference_time_and_not_later(hopper_refill_tiny_dataset: Path):
    from neuraldem.data.normalization import HopperNormalizer
    from neuraldem.scenes.hopper_refill.targets import reference_fields_at

    m = Manifest.load(hopper_refill_tiny_dataset)
    rec = m.usable()[0]
    with RefillFile(hopper_refill_tiny_dataset / str(rec.file)) as f:
        norm = HopperNormalizer(box_lo=[-1.0] * 3, box_hi=[1.0] * 3, horizon=0.25, scalar_lo={}, scalar_hi={})
        still = PersistenceRefillQuery(f, norm, radius=0.006)
        k_ref = 10
        t_ref = float(f.times[k_ref])
        rows_r, pos_r = f.frame(k_ref)
        occ, transport, residence = still.fields(t_ref, t_ref, pos_r)
        assert occ.min() == 1.0 and residence.max() == 0.0
        truth = reference_fields_at(pos_r, t_ref, t_ref, rows_r, pos_r, rows_r, pos_r, f.insert_times, 0.006)
        np.testing.assert_allclose(transport, truth.transport)
        # later material has moved and new material has come in: the persistence answer is wrong
        k = k_ref + 3  # 0.15 s: the tiny hopper turns its material over in ~0.3 s
        rows_t, pos_t = f.frame(k)
        later = reference_fields_at(pos_t, float(f.times[k]), t_ref, rows_t, pos_t, rows_r, pos_r, f.insert_times,
                                    0.006)
        _, transport, residence = still.fields(float(f.times[k]), t_ref, pos_t)
        assert later.new.any() and np.any(residence[later.new] > later.residence[later.new])
        old = later.occupied & ~later.new
        assert np.median(np.linalg.norm(transport[old] - later.transport[old], axis=1)) > 0.001


def test_checkpoint_is_scored_with_metrics_and_figures(refill_tiny_checkpoint: Path, hopper_refill_tiny_dataset: Path,
                                                       tmp_path: Path):
    out = tmp_path / "eval"
    result = evaluate_refill_checkpoint(refill_tiny_checkpoint, out, hopper_refill_tiny_dataset.parent,
                                        dataset_dir=hopper_refill_tiny_dataset, time_stride=4)
    agg = result["aggregate"]
    assert agg["n_sims"] == 1 and result["horizon"] == 0.25
    assert 0.0 <= agg["layer_fraction_error"] <= 1.0 and 0.0 <= agg["label_agreement"] <= 1.0
    assert np.isfinite(agg["transport_mse"]) and np.isfinite(agg["residence_mse"])
    sim = json.loads((out / "metrics.json").read_text())["simulations"][0]
    assert sim["rtd_median_particles_s"] > 0 and np.isfinite(sim["rtd_median_truth_s"])
    assert sim["rtd_answer_cpu_s"] > 0 and sim["solver_cpu_s"] == Manifest.load(hopper_refill_tiny_dataset).record(
        sim["sim_id"]).cost["cpu_s"]
    assert (out / "refill_transport.png").stat().st_size > 0 and (out / "refill_rtd.png").stat().st_size > 0
    import meshio

    later = meshio.read(out / "vtk" / f"{sim['sim_id']}_refill_transport_0001.vtu")
    assert set(later.point_data) == {"label_dem", "label_model"} and len(later.points) > 0
    assert "timestep" in (out / "vtk" / f"{sim['sim_id']}_refill_transport.pvd").read_text()
    still = result["persistence"]  # scored the same way; material has moved and new material come in
    assert still["n_sims"] == 1 and still["label_agreement"] < 1.0 and still["residence_mse"] > 0.0
    assert result["new_tolerance_s"] == pytest.approx(0.02 * 0.25)  # MODEL_NEW_TOLERANCE of the window
    with pytest.raises(DataError, match=r"refill.new_tolerance=2 \(of the 0.25-s window\) must be >= 0 and shorter"):
        evaluate_refill_checkpoint(refill_tiny_checkpoint, out, hopper_refill_tiny_dataset.parent,
                                   dataset_dir=hopper_refill_tiny_dataset, new_tolerance=2.0)
    with pytest.raises(DataError, match=r"refill.t_ref=1.9 s \+ horizon 0.25 s is past the end"):
        evaluate_refill_checkpoint(refill_tiny_checkpoint, out, hopper_refill_tiny_dataset.parent,
                                   dataset_dir=hopper_refill_tiny_dataset, t_ref=1.9)
    with pytest.raises(DataError, match=r"refill.horizon=1.0 must be in \(0, 0.25\] s"):
        evaluate_refill_checkpoint(refill_tiny_checkpoint, out, hopper_refill_tiny_dataset.parent,
                                   dataset_dir=hopper_refill_tiny_dataset, horizon=1.0)
