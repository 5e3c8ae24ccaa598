"""The GNS as a point of the hopper's speed-accuracy chart, on the real tiny LIGGGHTS dataset: exact
accelerations give zero error, a rollout that breaks gives no error and says why, the wrong scene is refused."""

from __future__ import annotations

import numpy as np
import pytest

from neuraldem.bench import stability_maps as hopper_stability
from neuraldem.bench.__main__ import main as bench_main
from neuraldem.data.manifest import require_dataset
from neuraldem.errors import ConfigError
from neuraldem.gns.bench.points import exit_times, gns_point
from neuraldem.gns.datamodule import ParticleRun
from neuraldem.gns.rollout import load_gns_checkpoint
from neuraldem.scenes.hopper.analysis.scoring import HOPPER_ERRORS
from tests.helpers import oracle, train_tiny_gns

pytestmark = pytest.mark.solver


@pytest.fixture(scope="module")
def hopper_gns(hopper_tiny_dataset, tmp_path_factory):
    return train_tiny_gns(hopper_tiny_dataset, "hopper_tiny", tmp_path_factory.mktemp("gns") / "hopper.ckpt")


def stored_oracle(dataset, sim_id: str):
    """The stored run's own accelerations (history 2, as train_tiny_gns trains)."""
    m = require_dataset(dataset, "hopper_tiny")
    with ParticleRun(dataset / str(m.record(sim_id).file), "hopper", m.scene) as run:
        return oracle(run, 2)


def first_test_sim(dataset, ckpt) -> str:
    meta = load_gns_checkpoint(ckpt).metadata
    m = require_dataset(dataset, "hopper_tiny")
    return (m.split_ids(meta["split"], "test") or m.split_ids(meta["split"], "val"))[0]


def test_exact_accelerations_score_zero_error(hopper_gns, hopper_tiny_dataset):
    sim = first_test_sim(hopper_tiny_dataset, hopper_gns)
    p = gns_point(hopper_gns, n_sims=1, dataset_dir=hopper_tiny_dataset, label="oracle",
                  accelerate=stored_oracle(hopper_tiny_dataset, sim))
    assert p["method"] == "GNS" and p["n_failed"] == 0 and p["n_sims"] == 1
    assert set(p["errors"]) == set(HOPPER_ERRORS)
    for key, value in p["errors"].items():
        assert value == pytest.approx(0.0, abs=1e-6), key
    s = p["simulations"][0]
    assert s["sim_id"] == sim and s["steps_done"] == s["steps"] and s["failed_at"] is None
    assert s["truth"]["residual_fraction"] < 1.0  # the tiny hopper drains: the zero is not trivial
    assert p["time_to_answer_s"] > 0 and p["size"]["parameters"] > 0


def test_a_rollout_that_breaks_has_no_error_and_says_why(hopper_gns, hopper_tiny_dataset):
    exact = stored_oracle(hopper_tiny_dataset, first_test_sim(hopper_tiny_dataset, hopper_gns))
    p = gns_point(hopper_gns, n_sims=1, dataset_dir=hopper_tiny_dataset,
                  accelerate=lambda step, inputs: np.full_like(exact(step, inputs), np.nan))
    assert p["errors"] == {} and p["n_failed"] == 1
    assert "NaN" in p["failures"][0]["reason"] or "particle count" in p["failures"][0]["reason"]
    assert p["failures"][0]["reason"].startswith("step 1:")
    # one step computed (and refused) stands for the whole trajectory's time, scaled, and says so
    s = p["simulations"][0]
    assert p["time_to_answer_s"] == pytest.approx(s["rollout_wall_s"] * s["steps"])
    assert p["timing"]["source"].startswith("extrapolated")


def test_the_trained_model_gives_a_point(hopper_gns, hopper_tiny_dataset):
    p = gns_point(hopper_gns, n_sims=1, dataset_dir=hopper_tiny_dataset)
    s = p["simulations"][0]
    # a 3-step model may leave the box; either it answered (finite errors) or it says where it failed
    if p["n_failed"]:
        assert p["errors"] == {} and s["failure"]
    else:
        assert all(np.isfinite(v) for v in p["errors"].values())
        assert s["steps_done"] == s["steps"]


def test_a_bed_gns_is_refused(fb_tiny_dataset, evaluated_runs, tiny_checkpoint, tmp_path, capsys):
    ckpt = train_tiny_gns(fb_tiny_dataset, "fb_tiny", tmp_path / "fb.ckpt")
    with pytest.raises(ConfigError, match="gns_hopper"):
        gns_point(ckpt, n_sims=1)
    # the benchmarks refuse it before measuring anything
    with pytest.raises(ConfigError, match="gns_hopper"):
        hopper_stability.run([tiny_checkpoint], [ckpt])
    out = tmp_path / "sa.json"
    assert bench_main(["speed_accuracy", f"runs=[{evaluated_runs / 'tiny'}]", "skip_solver=true", f"gns_ckpt=[{ckpt}]",
                       f"out={out}"]) == 2
    assert "gns_hopper" in capsys.readouterr().err and not out.exists()


def test_exit_times_are_the_first_missing_snapshot():
    times = np.array([0.0, 0.5, 1.0])
    pos = np.zeros((3, 2, 3))
    pos[2, 0] = np.nan
    np.testing.assert_array_equal(exit_times(times, pos), [1.0, np.nan])
