"""DPMFoam vs the fluidized-bed rollout: ratios on known timings (fake clock), the benchmark on the tiny
dataset and checkpoint (manifest costs, and a fresh DPMFoam run of the same trajectory), bad input."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from neuraldem.bench.__main__ import main as bench_main
from neuraldem.bench.timing import Sample, Timing
from neuraldem.scenes.fluidized_bed.bench import speed as fb_speed
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.sim.foam_reader import FoamCase
from tests.bench.test_timing import FakeClock


def _fake_rollout(fake: FakeClock, steps_done: int, diverged_at: int | None):
    def rollout(stepper, state, steps, limits=None, progress=True):
        fake.advance(0.5, 0.8)
        return SimpleNamespace(steps_done=steps_done, diverged_at=diverged_at, divergence="x" if diverged_at else "")
    return rollout


@pytest.mark.parametrize(("diverged_at", "computed"), [(None, 20), (5, 5)])
def test_surrogate_time_per_simulated_second(monkeypatch: pytest.MonkeyPatch, diverged_at, computed):
    """0.5 s wall / 0.8 s CPU per rollout of `computed` steps of 0.01 s (a diverged rollout counts the steps it
    computed, the diverging one included)."""
    fake = FakeClock()
    monkeypatch.setattr(fb_speed, "rollout", _fake_rollout(fake, 20 if diverged_at is None else 4, diverged_at))
    monkeypatch.setattr(fb_speed, "ModelStepper", lambda *args, **kwargs: None)
    module = SimpleNamespace(norm=SimpleNamespace(dt=0.01))
    t = fb_speed.surrogate_timing(module, 1.2, state=None, steps=20, repeats=3, threads=1, clock=fake.clock())
    assert t.median.wall_s == pytest.approx(0.5 / (computed * 0.01))
    assert t.median.cpu_s == pytest.approx(0.8 / (computed * 0.01))
    d = t.as_dict()
    assert d["repeats"] == 3 and d["steps_computed"] == computed and d["diverged_at"] == diverged_at
    assert d["per_run"]["median_wall_s"] == pytest.approx(0.5) and d["unit"] == "seconds per simulated second"


def test_ratios_are_solver_over_surrogate_medians():
    """Solver runs of 0.25 simulated s: medians 11 s wall / 9.2 s CPU per run = 44 / 36.8 per simulated s;
    surrogate medians 0.2 / 0.4 s per simulated s on one thread, 0.1 / 0.5 on two."""
    solver = Timing([Sample(10.0, 9.0), Sample(12.0, 9.5), Sample(11.0, 9.2)]).scaled(1 / 0.25)
    one = Timing([Sample(0.2, 0.4), Sample(0.3, 0.5), Sample(0.1, 0.3)], notes={"runtime": "torch", "torch_threads": 1})
    two = Timing([Sample(0.1, 0.5)], notes={"runtime": "onnx", "torch_threads": 2})
    rows = fb_speed.compare({"DPMFoam, measured": solver}, {"torch, 1 thread(s)": one, "onnx, 2 thread(s)": two})
    assert [(r["solver"], r["surrogate_runtime"], r["surrogate_threads"]) for r in rows] == [
        ("DPMFoam, measured", "torch", 1), ("DPMFoam, measured", "onnx", 2)]
    assert rows[0]["solver_wall_s"] == pytest.approx(44.0) and rows[0]["solver_cpu_s"] == pytest.approx(36.8)
    assert rows[0]["speedup_wall"] == pytest.approx(220.0) and rows[0]["speedup_cpu"] == pytest.approx(92.0)
    assert rows[1]["speedup_wall"] == pytest.approx(440.0) and rows[1]["speedup_cpu"] == pytest.approx(73.6)


def _check_rows(r: dict) -> None:
    for row in r["side_by_side"]:
        solver = r["solver"][row["solver"]]
        surrogate = r["surrogate"][row["surrogate"]]
        assert (surrogate["runtime"], surrogate["torch_threads"]) == (row["surrogate_runtime"],
                                                                      row["surrogate_threads"])
        assert row["solver_cpu_s"] == solver["median_cpu_s"] and row["surrogate_cpu_s"] == surrogate["median_cpu_s"]
        assert row["speedup_cpu"] == pytest.approx(row["solver_cpu_s"] / row["surrogate_cpu_s"])
        assert row["speedup_wall"] == pytest.approx(row["solver_wall_s"] / row["surrogate_wall_s"])
        assert row["speedup_cpu"] > 0 and row["speedup_wall"] > 0


def test_with_the_manifest_costs(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path, tmp_path: Path):
    argv = ["fb-speed", f"ckpt={fb_tiny_checkpoint}", f"dataset={fb_tiny_dataset}", "reuse_dataset=true",
            "repeats=2", "rollout_steps=3", "threads=[1,2]", f"out={tmp_path}"]
    assert bench_main(argv) == 0
    data = json.loads((tmp_path / "fb_speed.json").read_text())  # --out as a folder
    assert data["benchmark"] == "fb_speed" and data["machine"]["cpu_count"] >= 1
    assert data["command"].startswith("neuraldem bench fb_speed ckpt=")  # canonical name
    r = data["results"]
    assert r["sim_id"] == "sim_0002" and r["inlet_velocity"] == pytest.approx(2.041831)  # the test velocity
    assert r["extrapolation"] and r["n_particles"] == 300 and r["cells"] == [6, 1, 15]
    assert list(r["solver"]) == ["DPMFoam, dataset manifest"]
    recorded = r["solver"]["DPMFoam, dataset manifest"]
    assert recorded["source"].startswith("dataset manifest") and "not re-run" in recorded["source"]
    manifest = json.loads((fb_tiny_dataset / "manifest.json").read_text())
    per_s = [s["cost"]["solver_cpu_s"] / s["cost"]["simulated_s"] for s in manifest["simulations"]
             if s["status"] == "ok"]
    assert recorded["repeats"] == len(per_s) and recorded["median_cpu_s"] == pytest.approx(float(np.median(per_s)))
    assert recorded["per_simulation"]["repeats"] == len(per_s)
    # both runtimes by default, each at every thread count
    assert set(r["surrogate"]) == {"torch, 1 thread(s)", "torch, 2 thread(s)", "onnx, 1 thread(s)",
                                   "onnx, 2 thread(s)"}
    for label, s in r["surrogate"].items():
        assert label == f"{s['runtime']}, {s['torch_threads']} thread(s)"
        assert s["repeats"] == 2 and s["source"] == "measured"
        assert 1 <= s["steps_computed"] <= 3 and s["steps_requested"] == 3
        assert s["median_wall_s"] == pytest.approx(s["per_run"]["median_wall_s"] / s["simulated_s"])
    assert len(r["side_by_side"]) == 4
    _check_rows(r)
    md = (tmp_path / "fb_speed.md").read_text()
    assert "| DPMFoam, dataset manifest | torch | 1 |" in md and "| DPMFoam, dataset manifest | onnx | 2 |" in md
    assert (tmp_path / "fb_speed.png").stat().st_size > 0


def test_mirror_alternation_is_timed_when_asked(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path, tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch):
    """rollout.mirror_alternate=true times the rollout as the model is used (results/fluidized_bed/recipe.md) and
    says so in the record."""
    seen = []
    real = fb_speed.ModelStepper

    def recording(*args, **kwargs):
        stepper = real(*args, **kwargs)
        seen.append(stepper.stability.mirror_alternate)
        return stepper

    monkeypatch.setattr(fb_speed, "ModelStepper", recording)
    argv = ["fb-speed", f"ckpt={fb_tiny_checkpoint}", f"dataset={fb_tiny_dataset}", "reuse_dataset=true",
            "repeats=1", "rollout_steps=2", "threads=1", "runtime=torch", "rollout.mirror_alternate=true",
            f"out={tmp_path}"]
    assert bench_main(argv) == 0
    assert seen == [True, True]  # the warm-up and the timed rollout
    results = json.loads((tmp_path / "fb_speed.json").read_text())["results"]
    assert results["mirror_alternate"] is True and results["rollout_noise"] is None


@pytest.mark.solver
def test_fresh_dpmfoam_run_of_the_same_trajectory(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path, tmp_path: Path):
    """0.05 s spin-up + 0.01 s: the run reproduces the dataset trajectory's first snapshot (same scene, inlet
    velocity and packing seed) and its cost per simulated second is that of the run over 0.06 s."""
    work = tmp_path / "work"
    plan = fb_speed.prepare(fb_tiny_checkpoint, fb_tiny_dataset, "sim_0000", repeats=1, solver_repeats=1,
                            sim_seconds=0.01, rollout_steps=2, threads=[1], reuse_dataset=False, workdir=work,
                            keep_runs=True, runtimes=["torch"])
    r = fb_speed.measure(plan)
    measured = r["solver"]["DPMFoam, measured"]
    assert measured["source"] == "measured" and measured["repeats"] == 1
    assert measured["simulated_s"] == pytest.approx(0.06) and measured["stored_s"] == pytest.approx(0.01)
    assert measured["per_run"]["median_cpu_s"] > 0
    assert measured["median_cpu_s"] == pytest.approx(measured["per_run"]["median_cpu_s"] / 0.06)
    assert measured["median_wall_s"] == pytest.approx(measured["per_run"]["median_wall_s"] / 0.06)
    assert [row["solver"] for row in r["side_by_side"]] == ["DPMFoam, measured", "DPMFoam, dataset manifest"]
    _check_rows(r)
    case = FoamCase(work / "repeat_0")
    name = next(n for v, n in case.times() if abs(v - 0.05) < 1e-9)
    with BedFile(fb_tiny_dataset / "sims" / "sim_0000.h5") as f:
        np.testing.assert_allclose(case.cloud(name).positions, f.positions(0), atol=1e-6)


def test_without_keep_runs_the_run_folders_go(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path, tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch):
    calls = []

    def fake_run(scene, velocity, duration, folder, seed):
        calls.append((velocity, duration, seed))
        folder.mkdir(parents=True)
        return SimpleNamespace(status="failed", reason="boom", cost={}, diagnostics={})

    monkeypatch.setattr(fb_speed, "run_fluidized_bed", fake_run)
    plan = fb_speed.prepare(fb_tiny_checkpoint, fb_tiny_dataset, "sim_0001", 1, 2, 0.01, 2, [1], False, tmp_path)
    with pytest.raises(fb_speed.SolverError, match=r"DPMFoam run of sim_0001 \(1\.22853 m/s, 0\.06 s\) failed: boom"):
        fb_speed.measure(plan)
    manifest = json.loads((fb_tiny_dataset / "manifest.json").read_text())
    from neuraldem.scenes.fluidized_bed.dataset.datagen import packing_seed

    assert calls == [(1.228531, 0.01, packing_seed(manifest["parameters"]["seed"], 1))]
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(("args", "message"), [
    (["sim_seconds=0.015"], ("sim_seconds=0.015 is invalid: must be a positive multiple of the "
                             "scene's snapshot interval 0.01 s")),
    (["threads=0"], "config value threads[0]=0 is invalid: must be a positive integer"),
    (["runtime=tensorrt"], "runtime[0]='tensorrt' is invalid: choose torch or onnx"),
    (["repeats=0"], "config value repeats=0 is invalid"),
    (["rollout_steps=-2"], "config value rollout_steps=-2 is invalid"),
    (["rollout.rollout_noise=-1"], "rollout.rollout_noise=-1 is invalid: must be a number in [0, 10]"),
    (["rollout.advection_correction=1"], "fb_speed: unknown option rollout.advection_correction=: the options are"),
    (["sim=sim_9999"], "simulation 'sim_9999' is not in the manifest of dataset 'fb_tiny'"),
    (["out=speed.txt"], "out=speed.txt is invalid: pass a .json file or a folder"),
])
def test_bad_values_fail_with_one_line(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path, tmp_path: Path,
                                       capsys: pytest.CaptureFixture, args, message):
    out = [f"out={tmp_path / 'x.json'}"] if not any(a.startswith("out=") for a in args) else []
    argv = ["fb_speed", f"ckpt={fb_tiny_checkpoint}", f"dataset={fb_tiny_dataset}", "reuse_dataset=true", *out, *args]
    with pytest.raises(SystemExit) if args[0].startswith("rollout.advection") else contextlib.nullcontext():
        assert bench_main(argv) == 2  # (an unknown key ends the parse: SystemExit 2)
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and message in err[0] and err[0].startswith("neuraldem: error: "), err
    assert not (tmp_path / "x.json").exists()


def test_a_hopper_checkpoint_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture):
    hopper = tmp_path / "hopper.ckpt"
    torch.save({"hyper_parameters": {"metadata": {"kind": "hopper", "data_name": "hopper_tiny"}}}, hopper)
    assert bench_main(["fb_speed", f"ckpt={hopper}", f"out={tmp_path / 'x.json'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "is a 'hopper' checkpoint" in err and "needs a fluidized_bed model" in err
    assert not (tmp_path / "x.json").exists()
