"""Stability map of fluidized-bed surrogates: the velocity grid, the map of two checkpoints on the tiny data,
an injected divergence and an injected solid-volume drift reported as failures at their step, a collapsed bed
(finite, mass kept) reported as a failure inside the trained range only, bad options."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from neuraldem.bench.__main__ import main as bench_main
from neuraldem.errors import DataError
from neuraldem.scenes.fluidized_bed.bench import stability_map as fb_stability
from neuraldem.scenes.fluidized_bed.bench.stability_map import BedReference, merge_maps
from neuraldem.scenes.fluidized_bed.surrogate.rollout import BedState, DataStepper
from tests.scenes.fluidized_bed.surrogate.test_rollout import TRAINED_VELOCITY, Inject, _nan


def test_velocity_grid_spans_beyond_the_trained_range():
    assert fb_stability.velocity_grid(1.0, 2.0, 5) == [0.8, 1.0, 1.2, 1.6, 2.0, 2.4]
    assert fb_stability.velocity_grid(1.5, 1.5, 3) == [1.2, 1.5, 1.8]  # one trained velocity
    assert fb_stability.velocity_grid(1.0, 2.0, 1) == [1.0, 2.0]


def test_a_velocity_step_scans_the_trained_range_only():
    assert fb_stability.velocity_grid(1.0, 1.2, 9, step=0.05) == [1.0, 1.05, 1.1, 1.15, 1.2]
    assert fb_stability.velocity_grid(1.0, 1.23, 9, step=0.1) == [1.0, 1.1, 1.2, 1.23]  # the trained end kept


def test_map_of_two_checkpoints(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path, tmp_path: Path):
    """The same checkpoint twice stands in for a model and its ablation: two series, same velocities."""
    out = tmp_path / "map.json"
    argv = ["fb-stability", f"ckpt=[{fb_tiny_checkpoint},{fb_tiny_checkpoint}]", "labels=[model,no noise]",
            "n_velocities=3", "steps=3", f"dataset={fb_tiny_dataset}", f"out={out}"]
    assert bench_main(argv) == 0
    data = json.loads(out.read_text())
    assert data["benchmark"] == "fb_stability" and data["command"].startswith("neuraldem bench fb_stability")
    r = data["results"]
    v = TRAINED_VELOCITY
    assert r["velocities"] == [round(0.8 * v, 6), v, round(1.2 * v, 6)] and r["steps"] == 3
    assert r["drift_limit_pct"] == 5.0 and r["limits"] == {"max_packing": 0.74, "tolerance": 0.05}
    assert [s["label"] for s in r["series"]] == ["model", "no noise"]
    for s in r["series"]:
        assert s["trained_velocity_range"] == [v, v] and s["training_horizon_steps"] == 20
        assert [p["inlet_velocity"] for p in s["points"]] == r["velocities"]
        assert [p["extrapolation"] for p in s["points"]] == [True, False, True]
        for p in s["points"]:
            assert 0 <= p["steps_done"] <= p["steps_requested"] == 3
            assert 0 <= p["steps_stable"] <= 3 and p["max_abs_drift_pct"] >= abs(p["drift_pct_end"])
            assert p["failed"] == (p["steps_to_failure"] is not None) and p["initial_state"].startswith("fb_tiny/")
            if not p["failed"]:
                assert p["steps_stable"] == p["steps_done"] == 3 and abs(p["drift_pct_end"]) <= 5.0
        assert s["n_failed"] == sum(not p["ok"] for p in s["points"])
        assert s["bed_reference"]["velocities"] == [v] and s["bed_reference"]["settle_steps"] == 20 // 3
        for p in s["points"]:  # 3 steps end before the start-up (6 steps) is over: no bed height to judge
            assert p["bed_height_mm"] is None and not p["bed_checked"] and not p["bed_failed"]
    assert r["series"][0]["points"] == r["series"][1]["points"]  # same model, same seed: same map
    assert out.with_suffix(".png").stat().st_size > 0


def test_rollout_options_reach_every_rollout_and_the_record(fb_tiny_flux_checkpoint: Path, fb_tiny_dataset: Path,
                                                            tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """rollout.advection_correction= / rollout.mirror_alternate= (as the model is used:
    results/fluidized_bed/recipe.md) go to
    each rollout's stepper and into the map's record."""
    seen = []
    real = fb_stability.bed_rollout.ModelStepper

    def recording(*args, **kwargs):
        stepper = real(*args, **kwargs)
        seen.append((stepper.stability.advection_correction, stepper.stability.mirror_alternate))
        return stepper

    monkeypatch.setattr(fb_stability.bed_rollout, "ModelStepper", recording)
    out = tmp_path / "map.json"
    assert bench_main(["fb_stability", f"ckpt={fb_tiny_flux_checkpoint}", f"velocities=[{TRAINED_VELOCITY},1.3]",
                       "steps=2", "rollout.advection_correction=1", "rollout.mirror_alternate=true",
                       f"dataset={fb_tiny_dataset}", f"out={out}"]) == 0
    assert seen == [(1.0, True), (1.0, True)]  # both velocities
    r = json.loads(out.read_text())["results"]
    assert r["advection_correction"] == 1.0 and r["mirror_alternate"] is True and r["rollout_noise"] is None
    seen.clear()
    fb_stability.run([fb_tiny_flux_checkpoint], velocities=[TRAINED_VELOCITY], steps=2, dataset_dir=fb_tiny_dataset,
                     progress=False)
    assert seen == [(0.75, False)]  # as trained


def test_injected_divergence_is_a_failure_at_its_step(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path):
    """The ground truth replayed (it holds its mass) with NaN injected at step 5."""
    r = fb_stability.run([fb_tiny_checkpoint], velocities=[TRAINED_VELOCITY, 2.0], steps=8,
                         dataset_dir=fb_tiny_dataset, progress=False,
                         make_stepper=lambda module, v, f: Inject(DataStepper(f), at=5, spoil=_nan))
    for p in r["series"][0]["points"]:
        assert p["failed"] and p["steps_to_failure"] == p["steps_to_divergence"] == 5 == p["steps_stable"]
        assert p["steps_done"] == 4 and p["failure"].startswith("diverged: NaN/inf in the predicted fluid velocity")
    assert r["series"][0]["n_failed"] == 2


class Drifting:
    """Replays the stored trajectory with its solid fraction scaled by factor**k at step k: a surrogate that
    creates 2 % of the bed's mass per step (drift 4.04 % at step 2, 6.12 % at step 3)."""

    def __init__(self, inner: DataStepper, factor: float):
        self.inner, self.factor, self.dt, self.calls = inner, factor, inner.dt, 0

    def step(self, state: BedState) -> BedState:
        self.calls += 1
        nxt = self.inner.step(state)
        nxt.solid_fraction = nxt.solid_fraction * self.factor**self.calls
        return nxt


@pytest.mark.parametrize(("limit", "failed_at"), [(5.0, 3), (20.0, None)])
def test_solid_volume_drift_beyond_the_limit_is_a_failure(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path,
                                                          limit, failed_at):
    r = fb_stability.run([fb_tiny_checkpoint], velocities=[TRAINED_VELOCITY], steps=6, dataset_dir=fb_tiny_dataset,
                         drift_limit_pct=limit, progress=False,
                         make_stepper=lambda module, v, f: Drifting(DataStepper(f), 1.02))
    p = r["series"][0]["points"][0]
    assert p["steps_to_divergence"] is None and p["steps_done"] == 6
    assert p["drift_pct_end"] == pytest.approx(100 * (1.02**6 - 1), abs=0.01)  # the ground truth holds its mass
    assert p["steps_to_failure"] == p["steps_to_drift_limit"] == failed_at and p["failed"] == (failed_at is not None)
    if failed_at:
        assert p["failure"] == "solid volume drift +6.12 % beyond 5 %" and p["steps_stable"] == 3
    else:
        assert p["failure"] == "" and p["steps_stable"] == 6


def test_bed_reference_interpolates_inside_the_training_velocities_only():
    ref = BedReference(np.array([1.0, 2.0]), np.array([0.040, 0.050]), ["a", "b"], 10, 0.95)
    assert ref.at(1.5) == pytest.approx(0.045) and ref.at(1.0) == pytest.approx(0.040) and ref.at(2.0) == 0.05
    assert ref.at(0.99) is None and ref.at(2.01) is None


class Collapsing:
    """Replays the stored trajectory with each column's solids settled at the bottom at solid fraction
    `packing` (a bed compacted below CFD-DEM's): the total solid volume is kept and every value finite and
    below the divergence limit's maximum packing (0.74), but the bed is lower (fb_tiny: 11.6 mm against 15.0)."""

    def __init__(self, inner: DataStepper, packing: float = 0.72):
        self.inner, self.packing, self.dt = inner, packing, inner.dt

    def step(self, state: BedState) -> BedState:
        nxt = self.inner.step(state)
        a = nxt.solid_fraction
        layers = a.sum(axis=-1, keepdims=True) / self.packing  # column volume in layers' worth
        z = np.arange(a.shape[-1])
        nxt.solid_fraction = self.packing * np.clip(layers - z, 0.0, 1.0)
        return nxt


@pytest.mark.parametrize("collapse", [False, True])
def test_a_bed_off_cfd_dem_fails_inside_the_trained_range_only(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path,
                                                               collapse: bool):
    """The ground truth replayed holds CFD-DEM's bed height (within the limit); squashed, the same replay keeps
    its volume and stays finite, yet fails on the bed at the trained velocity, and is only reported outside."""
    def make(module, v, f):
        replay = DataStepper(f)
        return Collapsing(replay) if collapse else replay

    r = fb_stability.run([fb_tiny_checkpoint], velocities=[TRAINED_VELOCITY, 2.0], steps=12,
                         dataset_dir=fb_tiny_dataset, progress=False, make_stepper=make)
    inside, outside = r["series"][0]["points"]
    assert r["settle_steps"] == 6 and r["bed_limit_pct"] == 10.0
    for p in (inside, outside):
        assert not p["failed"] and abs(p["max_abs_drift_pct"]) < 1e-3 and p["bed_height_mm"] > 0
    assert inside["bed_checked"] and not outside["bed_checked"] and outside["bed_deviation_pct"] is None
    assert outside["ok"] and not outside["bed_failed"]
    if collapse:
        assert inside["bed_failed"] and not inside["ok"] and inside["bed_deviation_pct"] < -10
        assert inside["bed_failure"].startswith("bed height ") and "from CFD-DEM's" in inside["bed_failure"]
        assert r["series"][0]["n_failed"] == r["series"][0]["n_bed_failed"] == 1
    else:
        assert abs(inside["bed_deviation_pct"]) < 10 and inside["ok"] and r["series"][0]["n_failed"] == 0


@pytest.mark.parametrize(("args", "message"), [
    (["steps=0"], "config value steps=0 is invalid: must be a positive integer"),
    (["labels=[a,b]"], "labels=: 2 label(s) for 1 checkpoint(s)"),
    (["velocities=[1.2,0]"], "config value velocities[1]=0.0 is invalid: must be > 0.0"),
    (["drift_limit_pct=0"], "config value drift_limit_pct=0.0 is invalid: must be > 0.0"),
    (["n_velocities=0"], "config value n_velocities=0 is invalid"),
    (["bed_limit_pct=-5"], "config value bed_limit_pct=-5.0 is invalid: must be > 0.0"),
    (["settle_steps=-1"], "config value settle_steps=-1 is invalid"),
    (["velocity_step=0"], "config value velocity_step=0.0 is invalid: must be > 0.0"),
    (["velocity_step=0.01", "velocities=[1.2]"], "velocity_step= and velocities= both given"),
    (["rollout.rollout_noise=-1"], "rollout.rollout_noise=-1 is invalid: must be a number in [0, 10]"),
    (["rollout.advection_correction=2"], "rollout.advection_correction=2 is invalid: must be a number in [0, 1]"),
    (["rollout.mixing=stir"], "rollout.mixing=stir is invalid: must be one of absolute, advect"),
    (["out=map.csv"], "out=map.csv is invalid: pass a .json file or a folder"),
])
def test_bad_values_fail_with_one_line(fb_tiny_checkpoint: Path, tmp_path: Path, capsys: pytest.CaptureFixture,
                                       args, message):
    out = [f"out={tmp_path / 'x.json'}"] if not any(a.startswith("out=") for a in args) else []
    assert bench_main(["fb_stability", f"ckpt={fb_tiny_checkpoint}", *out, *args]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith(f"neuraldem: error: {message}"), err
    assert not (tmp_path / "x.json").exists()


def test_a_hopper_checkpoint_is_refused(fb_tiny_checkpoint: Path, tmp_path: Path, capsys: pytest.CaptureFixture):
    hopper = tmp_path / "hopper.ckpt"
    torch.save({"hyper_parameters": {"metadata": {"kind": "hopper", "data_name": "hopper_tiny"}}}, hopper)
    argv = ["fb_stability", f"ckpt=[{fb_tiny_checkpoint},{hopper}]", f"out={tmp_path / 'x.json'}"]
    assert bench_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "is a 'hopper' checkpoint" in err and "needs a fluidized_bed model" in err
    assert not (tmp_path / "x.json").exists()


def test_merged_maps_keep_every_series_and_refuse_mismatches():
    a = {"velocities": [1.0, 2.0], "steps": 10, "drift_limit_pct": 5.0, "limits": {"max_packing": 0.64},
         "series": [{"label": "model", "points": []}]}
    b = {**a, "limits": {"overlap_fraction": 0.5}, "series": [{"label": "gns", "method": "gns", "points": []}]}
    merged = merge_maps(a, b)
    assert [(s["label"], s["method"]) for s in merged["series"]] == [("model", "field surrogate"), ("gns", "gns")]
    assert merged["steps"] == 10 and len(merged["limits"]) == 2
    with pytest.raises(DataError, match="differ in velocities"):
        merge_maps(a, {**b, "velocities": [1.0]})
    with pytest.raises(DataError, match="share series labels"):
        merge_maps(a, a)
