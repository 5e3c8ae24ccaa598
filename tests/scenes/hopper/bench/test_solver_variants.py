"""Cheaper LIGGGHTS settings: parsing, what each does to the scene, and a real scored run on the tiny set."""

from __future__ import annotations

from pathlib import Path

import pytest

from neuraldem.errors import ConfigError
from neuraldem.scenes.hopper.bench.solver import dataset_scene, split_records
from neuraldem.scenes.hopper.bench.solver_variants import SolverVariant, score_variant
from neuraldem.scenes.hopper.solver import HopperScene


def test_variants_change_the_scene_as_documented():
    base = HopperScene()
    assert SolverVariant.parse("fewer:0.5").apply(base).n_particles == 2500
    coarse = SolverVariant.parse("coarser:2").apply(base)
    assert coarse.material.diameter == pytest.approx(0.02) and coarse.n_particles == 625  # same bulk volume
    assert SolverVariant.parse("dt:2").apply(base).material.dt == pytest.approx(2e-4)
    assert SolverVariant.parse("same:1").apply(base) == base
    assert SolverVariant.parse("coarser:1.5").label == "LIGGGHTS coarser x1.5"


@pytest.mark.parametrize("spec, message", [("bigger:2", "KIND:FACTOR"), ("fewer", "KIND:FACTOR"),
                                           ("fewer:2", "0 < F < 1"), ("dt:0.5", "K > 1"),
                                           ("same:2", "must be 1")])
def test_bad_variant_specs(spec: str, message: str):
    with pytest.raises(ConfigError, match=message):
        SolverVariant.parse(spec)


def test_a_variant_the_scene_cannot_take():
    with pytest.raises(ConfigError, match=r"solver variant dt:3.*snapshot_interval"):
        SolverVariant.parse("dt:3").apply(HopperScene())  # 0.05 s is no multiple of 3e-4 s
    with pytest.raises(ConfigError, match="outlet_diameter"):
        SolverVariant.parse("coarser:5").apply(HopperScene())  # 50 mm particles, 80 mm outlet


@pytest.mark.solver
def test_scored_against_the_reference_run(hopper_tiny_dataset: Path, tmp_path: Path):
    base, m = dataset_scene(hopper_tiny_dataset)
    records = split_records(m, "random")[:1]
    out = score_variant(SolverVariant.parse("fewer:0.5"), base, records, hopper_tiny_dataset, tmp_path)
    assert out["method"] == "liggghts" and out["scene"]["n_particles"] == 250 and out["n_failed"] == 0
    sim = out["simulations"][0]
    assert sim["truth"]["drainage_time"] == records[0].metrics["drainage_time"]  # the stored reference run
    expected = 100 * abs(sim["predicted"]["residual_fraction"] - sim["truth"]["residual_fraction"])
    assert out["errors"]["residual_mae_pp"] == pytest.approx(expected)
    assert out["time_to_answer_s"] >= sim["solver_wall_s"]
