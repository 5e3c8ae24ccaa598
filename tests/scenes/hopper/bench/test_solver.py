"""Solver-side benchmark arithmetic (log parsing, particle-steps, extrapolation, scene scaling) on known
numbers, and the drain profile of the real tiny dataset."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes.hopper.bench.solver import (
    DrainProfile,
    LoopTime,
    PhaseCost,
    dataset_scene,
    drain_profile_of_dataset,
    drain_rate,
    extrapolated_full_run,
    loop_times,
    phase_cost,
    scaled_scene,
    shortened_scene,
)
from neuraldem.scenes.hopper.solver import HopperGeometry, HopperScene, hopper_input
from neuraldem.sim.material import Material

LOG = """\
Loop time of 20 on 1 procs for 6000 steps with 1000 atoms, finish time Mon Nov 23 03:48:12 2026
NEURALDEM_OPEN_STEP 6000
Loop time of 1.5 on 1 procs for 1000 steps with 900 atoms, finish time Mon Nov 23 03:48:13 2026
Loop time of 2 on 1 procs for 1000 steps with 700 atoms, finish time Mon Nov 23 03:48:15 2026
"""


def test_loop_times_and_phases_from_a_log():
    assert loop_times(LOG) == [LoopTime(20.0, 6000, 1000), LoopTime(1.5, 1000, 900), LoopTime(2.0, 1000, 700)]
    cost = phase_cost(LOG, 1000)
    assert cost.settle_particle_steps == 6000 * 1000
    # the count is taken as linear within a chunk: (1000 + 900) / 2, then (900 + 700) / 2
    assert cost.chunk_particle_steps() == [950_000.0, 800_000.0]
    assert cost.drain_particle_steps == 1_750_000.0
    assert drain_rate(cost) == 800_000.0 / 2.0  # the last chunk: the flowing hopper
    d = cost.as_dict()
    assert d["settle_particle_steps_per_s"] == 300_000.0 and d["drain_chunks"] == 2
    with pytest.raises(DataError, match="Loop time"):
        phase_cost(LOG.splitlines()[0], 1000)


def test_extrapolation_arithmetic():
    cost = PhaseCost(LoopTime(20.0, 6000, 1000), [LoopTime(1.0, 1000, 1000), LoopTime(2.0, 1000, 1000)], 1000)
    rate = drain_rate(cost)
    assert rate == 500_000.0  # 1000 steps x 1000 particles in 2 s
    profile = DrainProfile(drain_time=4.0, remaining_fraction=0.25, source="test")
    # full drain: 5000 particles x (4 s / 1e-4 s) steps x 0.25 inside on average = 5e7 particle-steps
    assert profile.particle_steps(5000, 1e-4) == pytest.approx(5.0e7)
    out = extrapolated_full_run(5000, cost, profile, 1e-4)
    assert out["settle_s_measured"] == 20.0
    assert out["drain_s_extrapolated"] == pytest.approx(100.0)  # 5e7 / 5e5 per second
    assert out["full_run_s_extrapolated"] == pytest.approx(120.0)


def test_scaled_scene_keeps_the_shape():
    base = HopperScene()
    big = scaled_scene(base, 8 * base.n_particles)  # 8x the particles: diameters x2, settle x sqrt(2)
    assert big.n_particles == 40000
    assert big.hopper_diameter == pytest.approx(2 * base.hopper_diameter)
    assert big.outlet_diameter == pytest.approx(2 * base.outlet_diameter)
    assert big.settle_time == pytest.approx(math.sqrt(2) * base.settle_time)
    assert big.material == base.material
    with pytest.raises(ConfigError, match="n_particles"):
        scaled_scene(base, 0)


def test_shortened_scene_runs_two_chunks_of_the_given_steps():
    short = shortened_scene(HopperScene(), 1000)
    assert short.snapshot_interval == pytest.approx(0.1) and short.stall_time == pytest.approx(0.1)
    assert short.max_time == pytest.approx(0.2)
    text = hopper_input(short, HopperGeometry.for_angle(short, 30.0), Material(), [2, 3, 5])
    assert "variable k loop 2" in text and "run 1000" in text


def test_drain_profile_of_the_tiny_dataset(hopper_tiny_dataset: Path):
    profile = drain_profile_of_dataset(hopper_tiny_dataset, max_sims=3)
    m = json.loads((hopper_tiny_dataset / "manifest.json").read_text())
    durations = sorted(r["metrics"]["duration"] for r in m["simulations"] if r["status"] == "ok")
    assert durations[0] <= profile.drain_time <= durations[-1]
    assert 0.0 < profile.remaining_fraction <= 1.0
    assert "3 stored runs" in profile.source


def test_dataset_scene_errors(tmp_path: Path, hopper_tiny_dataset: Path):
    scene, m = dataset_scene(hopper_tiny_dataset)
    assert scene.n_particles == m.scene["hopper"]["n_particles"]
    with pytest.raises(DataError, match="no dataset at"):
        dataset_scene(tmp_path / "nothing")
