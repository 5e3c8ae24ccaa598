"""`neuraldem bench cluster_cost` on synthetic result files (made up here, labelled so: no solver runs) with
known answers: measured counts are read off, a power law is extrapolated exactly, CPU-hours scale with the
batch, and results of the wrong benchmark or lacking a field are refused by name."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.bench.cluster_cost import hopper_points, hopper_run_cost, main
from neuraldem.bench.report import write_results
from neuraldem.errors import DataError

COUNTS = (2000, 5000, 10000, 20000, 50000)


def settle(n: float) -> float:  # synthetic: 1e-3 N^1.25 s
    return 1e-3 * n ** 1.25


def drain(n: float) -> float:  # synthetic: 2e-3 N^1.1 s
    return 2e-3 * n ** 1.1


def synthetic_scaling(tmp_path: Path) -> Path:
    points = [{"n_particles": n, "measured": {"settle_s": settle(n), "drain_particle_steps_per_s": 2e6},
               "extrapolated": {"drain_s": drain(n), "full_run_s": settle(n) + drain(n)}} for n in COUNTS]
    points[1]["full_run_measured"] = {"process_cpu_s": 50.0}
    results = {"solver": {"points": points, "drain_profile": {"drain_time_s": 3.5}}}
    return write_results("hopper_scaling", results, command="synthetic", path=tmp_path / "hopper_scaling.json")


def synthetic_fb_speed(tmp_path: Path) -> Path:
    results = {"n_particles": 1000, "cells": [12, 1, 30], "dt": 0.01, "solver": {"DPMFoam, dataset manifest": {
        "median_cpu_s": 100.0, "repeats": 4, "dataset": "synthetic",
        "per_simulation": {"median_cpu_s": 320.0, "simulated_s": [3.2, 3.2, 3.2, 3.2]}}}}
    return write_results("fb_speed", results, command="synthetic", path=tmp_path / "fb_speed.json")


def test_measured_counts_are_read_and_a_power_law_is_extrapolated_exactly(tmp_path: Path):
    points = hopper_points(json.loads(synthetic_scaling(tmp_path).read_text())["results"])
    measured = hopper_run_cost(points, 5000)
    assert measured["run_s"] == pytest.approx(settle(5000) + drain(5000))
    assert "a full run measured 50 CPU s" in measured["source"]
    far = hopper_run_cost(points, 250000)
    assert far["settle_s_exponent"] == pytest.approx(1.25) and far["drain_s_exponent"] == pytest.approx(1.1)
    assert far["run_s"] == pytest.approx(settle(250000) + drain(250000), rel=1e-9)
    assert "extrapolated" in far["source"]


def test_cpu_hours_per_batch_and_the_bed(tmp_path: Path):
    out = tmp_path / "cluster_cost.json"
    assert main([f"hopper_scaling={synthetic_scaling(tmp_path)}", f"fb_speed={synthetic_fb_speed(tmp_path)}",
                 "hopper_runs=1000", "bed_trajectories=10", f"out={out}"]) == 0
    res = json.loads(out.read_text())["results"]
    by_n = {r["n_particles"]: r for r in res["hopper"]}
    assert by_n[50000]["cpu_hours_per_batch"] == pytest.approx((settle(50000) + drain(50000)) * 1000 / 3600)
    bed = {t["trajectory"]: t for t in res["bed_trajectories_cost"]}
    # fb_small: 0.2 s spin-up + 3 s (training) or 30 s (long), at 100 CPU s per simulated second
    assert bed["training (3 s stored)"]["cpu_s"] == pytest.approx(320.0)
    assert bed["long test (30 s stored)"]["cpu_hours_per_batch"] == pytest.approx(30.2 * 100 * 10 / 3600)
    assert "| 250,000 |" in out.with_suffix(".md").read_text()


def test_a_datasets_own_costs_are_its_manifests_medians(tmp_path: Path, hopper_tiny_dataset: Path):
    """The real tiny hopper dataset (LIGGGHTS, with characterization) adds its recorded costs; a dataset made
    without characterization is refused by name."""
    import numpy as np

    from neuraldem.bench.cluster_cost import dataset_costs
    from neuraldem.data.manifest import Manifest

    m = Manifest.load(hopper_tiny_dataset)
    costs = dataset_costs(hopper_tiny_dataset)
    key = "characterization_cpu_s"
    expected = np.median([r.cost[key] for r in m.simulations if key in r.cost])
    assert costs["median_cpu_s"] == pytest.approx(expected) and costs["n_particles"] == 500
    for r in m.simulations:
        r.cost.pop("characterization_cpu_s", None)
    m.save(tmp_path)
    with pytest.raises(DataError, match="records no characterization_cpu_s"):
        dataset_costs(tmp_path)


def test_wrong_or_incomplete_inputs_are_refused_by_name(tmp_path: Path):
    fb = synthetic_fb_speed(tmp_path)
    with pytest.raises(DataError, match="not 'hopper_scaling'"):
        main([f"hopper_scaling={fb}", f"fb_speed={fb}", f"out={tmp_path / 'x.json'}"])
    broken = write_results("hopper_scaling", {"solver": {}}, command="synthetic", path=tmp_path / "broken.json")
    with pytest.raises(DataError, match="lack solver.points"):
        main([f"hopper_scaling={broken}", f"fb_speed={fb}", f"out={tmp_path / 'x.json'}"])
