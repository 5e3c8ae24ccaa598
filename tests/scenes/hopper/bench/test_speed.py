"""Solver vs surrogate side by side: the ratios on known timings (fake clock injected, the timed work
replaced by stand-ins that advance it), and the whole benchmark on the tiny dataset and checkpoint."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from neuraldem.bench.__main__ import main as bench_main
from neuraldem.bench.timing import Sample, Timing
from neuraldem.data.manifest import SimRecord
from neuraldem.scenes.hopper.bench import speed as hopper_speed
from neuraldem.scenes.hopper.bench.surrogate import Question, untrained_surrogate
from tests.bench.test_timing import FakeClock


def test_ratios_from_known_timings(monkeypatch: pytest.MonkeyPatch):
    """Solver: simulation medians 11 s wall / 9.2 s CPU (given), post-processing 0.5 / 0.4 s per answer;
    surrogate 0.01 / 0.02 s per answer, both 'measured' on a fake clock: the speed-ups are exact."""
    fake = FakeClock()
    monkeypatch.setattr(hopper_speed, "dem_fields", lambda traj, q, radius: fake.advance(0.5, 0.4))
    monkeypatch.setattr(hopper_speed, "answer", lambda surrogate, q: fake.advance(0.01, 0.02))
    solver = Timing([Sample(10.0, 9.0), Sample(12.0, 9.5), Sample(11.0, 9.2)])
    q = Question(SimRecord("s", 0, {}), np.zeros(3), np.zeros((5, 3)))
    surrogate = untrained_surrogate("hopper_tiny", ["t", "alpha", "mu_s", "mu_r"])
    out = hopper_speed.measure(surrogate, {"all particle positions": q}, solver, traj=None, radius=0.006,
                               repeats=4, threads=1, clock=fake.clock())
    row = out["side_by_side"][0]
    assert row["solver_wall_s"] == pytest.approx(11.5) and row["solver_cpu_s"] == pytest.approx(9.6)
    assert row["surrogate_wall_s"] == pytest.approx(0.01) and row["surrogate_cpu_s"] == pytest.approx(0.02)
    assert row["speedup_wall"] == pytest.approx(1150.0)
    assert row["speedup_cpu"] == pytest.approx(480.0)
    assert out["details"]["all particle positions"]["surrogate"]["repeats"] == 4
    assert out["threads"] == {"surrogate_torch_threads": 1, "solver_threads": 1,
                              "solver_postprocess": "numpy/scipy, one thread"}


def test_reuse_dataset_takes_the_recorded_cost(tiny_checkpoint: Path, hopper_tiny_dataset: Path, tmp_path: Path):
    out = tmp_path / "speed.json"
    argv = ["hopper_speed", f"ckpt={tiny_checkpoint}", f"dataset={hopper_tiny_dataset}", "reuse_dataset=true",
            "repeats=1", "reduced_queries=25", "time_grid=solver", f"out={out}"]
    assert bench_main(argv) == 0
    data = json.loads(out.read_text())
    assert data["command"].startswith("neuraldem bench hopper_speed ckpt=")
    r = data["results"]
    sim = r["solver_simulation"]
    assert sim["source"].startswith("dataset manifest") and "not re-run" in sim["source"]
    manifest = json.loads((hopper_tiny_dataset / "manifest.json").read_text())
    recorded = sorted(s["cost"]["cpu_s"] for s in manifest["simulations"] if s["status"] == "ok")
    assert sim["repeats"] == len(recorded) and sim["median_cpu_s"] == pytest.approx(float(np.median(recorded)))
    rows = {row["question"]: row for row in r["side_by_side"]}
    assert set(rows) == {"all particle positions", "25 query points"}
    for row in rows.values():
        assert row["speedup_cpu"] == pytest.approx(row["solver_cpu_s"] / row["surrogate_cpu_s"])
        assert row["solver_cpu_s"] > sim["median_cpu_s"]  # simulation + post-processing
    assert r["details"]["25 query points"]["question"]["n_points"] == 25
    # time_grid=solver: the surrogate answers at exactly the stored run's snapshot times
    assert r["details"]["25 query points"]["question"]["n_times"] == r["solver_trajectory"]["n_snapshots"]
    assert "LIGGGHTS serial" in out.with_suffix(".md").read_text()


@pytest.mark.solver
def test_measured_solver_run(tiny_checkpoint: Path, hopper_tiny_dataset: Path, tmp_path: Path):
    out = tmp_path / "speed.json"
    argv = ["hopper_speed", f"ckpt={tiny_checkpoint}", f"dataset={hopper_tiny_dataset}", "solver_repeats=1",
            "repeats=1", "reduced_queries=25", f"workdir={tmp_path / 'w'}", f"out={out}"]
    assert bench_main(argv) == 0
    r = json.loads(out.read_text())["results"]
    assert r["solver_simulation"]["source"] == "measured" and r["solver_simulation"]["repeats"] == 1
    assert r["solver_simulation"]["median_cpu_s"] > 0
    assert r["solver_trajectory"]["n_particles"] == 500
    assert not any((tmp_path / "w").iterdir())  # run folders removed unless keep_runs=true


def test_bad_inputs_are_one_line(tiny_checkpoint: Path, tmp_path: Path, capsys: pytest.CaptureFixture):
    fb = tmp_path / "fb.ckpt"
    torch.save({"hyper_parameters": {"metadata": {"kind": "fluidized_bed", "data_name": "fb_tiny"}}}, fb)
    assert bench_main(["hopper_speed", f"ckpt={fb}", f"out={tmp_path / 'x.json'}"]) == 2
    assert "needs a hopper model" in capsys.readouterr().err
    assert bench_main(["hopper_speed", f"ckpt={tiny_checkpoint}", f"dataset={tmp_path / 'none'}",
                       "reuse_dataset=true", f"out={tmp_path / 'x.json'}"]) == 2
    assert "no dataset at" in capsys.readouterr().err
    assert bench_main(["hopper_speed", f"ckpt={tiny_checkpoint}", "threads=0"]) == 2
    assert "config value threads=0 is invalid" in capsys.readouterr().err
    assert not (tmp_path / "x.json").exists()
