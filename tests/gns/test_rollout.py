import json
from pathlib import Path

import numpy as np
import pytest

from neuraldem.data.manifest import require_dataset
from neuraldem.errors import DataError
from neuraldem.gns.datamodule import ParticleRun
from neuraldem.gns.rollout import (
    StabilityLimits,
    check_state,
    count_overlaps,
    hopper_particle_metrics,
    load_gns_checkpoint,
    model_accelerator,
    rollout,
    run_gns_rollout,
)
from tests.helpers import oracle, run_module, train_tiny_gns

LENIENT = StabilityLimits(box_tolerance_d=1e6, overlap_fraction=0.0, max_overlaps=10**9)


@pytest.fixture(scope="module")
def hopper_gns(hopper_tiny_dataset, tmp_path_factory):
    return train_tiny_gns(hopper_tiny_dataset, "hopper_tiny", tmp_path_factory.mktemp("gns") / "hopper.ckpt")


@pytest.fixture(scope="module")
def fb_gns(fb_tiny_dataset, tmp_path_factory):
    return train_tiny_gns(fb_tiny_dataset, "fb_tiny", tmp_path_factory.mktemp("gns") / "fb.ckpt")


def open_run(dataset: Path, name: str, sim: str) -> tuple[ParticleRun, object]:
    m = require_dataset(dataset, name)
    rec = m.record(sim)
    return ParticleRun(dataset / str(rec.file), m.kind, m.scene), rec


@pytest.mark.solver
@pytest.mark.parametrize("name", ["hopper_tiny", "fb_tiny"])
def test_exact_accelerations_reproduce_the_run_and_pass_every_check(name, request, hopper_gns, fb_gns):
    dataset = request.getfixturevalue(f"{name}_dataset")
    module = load_gns_checkpoint(hopper_gns if name == "hopper_tiny" else fb_gns)
    run, rec = open_run(dataset, name, "sim_0000")
    with run:
        steps = run.n_snapshots - 3
        r = rollout(oracle(run, 2), run, module.norm, module.norm.scalars(rec.conditioning()), steps)
        truth = run.positions()
    assert r.failed_at is None, r.failure
    assert r.positions.shape == truth.shape
    both = np.isfinite(truth).all(axis=2)
    assert np.array_equal(np.isfinite(r.positions).all(axis=2), both)
    np.testing.assert_allclose(r.positions[both], truth[both], atol=1e-8)
    if name == "hopper_tiny":  # the particle-count metrics of the rollout are the run's
        pred, true = hopper_particle_metrics(r.times, r.positions), hopper_particle_metrics(run.times, truth)
        np.testing.assert_allclose(list(pred.values()), list(true.values()), rtol=1e-9)
        assert pred["residual_fraction"] < 1.0 and np.isfinite(pred["drainage_time"])


@pytest.mark.solver
@pytest.mark.parametrize("name", ["hopper_tiny", "fb_tiny"])
def test_model_rollout_of_20_steps(name, request, hopper_gns, fb_gns, tmp_path):
    dataset = request.getfixturevalue(f"{name}_dataset")
    ckpt = hopper_gns if name == "hopper_tiny" else fb_gns
    module = load_gns_checkpoint(ckpt)
    run, rec = open_run(dataset, name, "sim_0000")
    with run:
        r = rollout(model_accelerator(module), run, module.norm, module.norm.scalars(rec.conditioning()), 20,
                    limits=LENIENT)
        n = run.n_particles
    assert r.failed_at is None and r.steps_done == 20
    assert r.positions.shape == (20 + 3, n, 3) and r.times.shape == (23,)
    result = run_gns_rollout(ckpt, tmp_path, "sim_0000", steps=5, dataset_dir=dataset, limits=LENIENT)
    assert result["steps_done"] == 5 and not result["failed"]
    assert json.loads((tmp_path / "gns_rollout.json").read_text())["sim_id"] == "sim_0000"
    key = "pred" if name == "hopper_tiny" else "summary_pred"
    assert set(result["metrics"][key]) >= ({"drainage_time", "residual_fraction"} if name == "hopper_tiny"
                                           else {"bed_height_mean", "lacey_final"})


def faulty(kind: str, run: ParticleRun, h: int):
    base = oracle(run, h)
    x = run.positions()

    def accelerate(step, inputs):
        a = base(step, inputs)
        if step < 3:
            return a
        k = h + step - 1
        alive = np.flatnonzero(np.isfinite(x[k]).all(axis=1))
        if kind == "nan":
            a[0] = np.nan
        elif kind == "box":
            a[0] = [1e6, 0.0, 0.0]
        elif kind == "overlap":  # particle 0 lands on particle 1
            p0, p1 = x[k, alive[0]], x[k, alive[1]]
            v0 = (x[k, alive[0]] - x[k - 1, alive[0]]) / run.dt
            v1 = (x[k + 1, alive[1]] - x[k, alive[1]]) / run.dt
            a[0] = (p1 + v1 * run.dt - p0 - v0 * run.dt) / run.dt**2
        elif kind == "count":
            a = a[1:]
        return a

    return accelerate


@pytest.mark.solver
@pytest.mark.parametrize(("kind", "reason"), [("nan", "NaN/inf"), ("box", "left the domain box"),
                                              ("overlap", "overlapping pair"), ("count", "particle count changed")])
def test_each_check_fires_at_its_step(kind, reason, fb_tiny_dataset, fb_gns):
    module = load_gns_checkpoint(fb_gns)
    run, rec = open_run(fb_tiny_dataset, "fb_tiny", "sim_0000")
    with run:
        r = rollout(faulty(kind, run, 2), run, module.norm, module.norm.scalars(rec.conditioning()), 10)
    assert r.failed_at == 3 and reason in r.failure, r.failure
    assert r.steps_done == 2 and np.isfinite(r.positions[:, 0]).all()  # the states before it are kept


def test_check_state_cases():
    pos = np.array([[0.5, 0.5, 0.5], [2.5, 0.5, 0.5], [0.5, 2.5, 0.5]])
    d = np.ones(3)
    lo, hi, limits = np.zeros(3), np.full(3, 3.0), StabilityLimits()
    assert check_state(pos, d, 0, 3, lo, hi, limits) == (None, 0)
    assert "particle count changed" in check_state(pos, d, 1, 3, lo, hi, limits)[0]  # one vanished
    assert "NaN" in check_state(np.where(np.eye(3, dtype=bool), np.nan, pos), d, 0, 3, lo, hi, limits)[0]
    out = pos.copy()
    out[1, 0] = 3.6  # 0.6 d outside, tolerance 0.5 d
    assert "left the domain" in check_state(out, d, 0, 3, lo, hi, limits)[0]
    close = pos.copy()
    close[1] = [0.8, 0.5, 0.5]
    problem, n = check_state(close, d, 0, 3, lo, hi, limits)
    assert "1 overlapping pair" in problem and n == 1
    assert count_overlaps(close, d, 0.2) == 0


def test_bad_limits_name_the_key():
    with pytest.raises(Exception, match="overlap_fraction=2"):
        StabilityLimits(overlap_fraction=2)


@pytest.mark.solver
def test_other_checkpoints_are_refused(fb_tiny_checkpoint):
    with pytest.raises(DataError, match="is a 'fluidized_bed' checkpoint"):
        load_gns_checkpoint(fb_tiny_checkpoint)


@pytest.mark.solver
def test_neuraldem_evaluate_takes_a_gns_checkpoint(hopper_gns, tmp_path):
    proc = run_module("neuraldem", "evaluate", f"ckpt={hopper_gns}", "gns.steps=3", f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 0, proc.stderr
    result = json.loads((tmp_path / "gns_rollout.json").read_text())
    assert result["steps_requested"] == 3 and result["sim_id"] in proc.stdout
    proc = run_module("neuraldem", "evaluate", f"ckpt={hopper_gns}", "gns.steps=0", f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 2 and "gns.steps" in proc.stderr
