"""The occupancy-radius diagnostic on a real tiny LIGGGHTS dataset."""

from __future__ import annotations

from pathlib import Path

import pytest

from neuraldem.scenes.hopper.dataset.occupancy_coverage import coverage_rows, main

pytestmark = pytest.mark.solver


def test_a_larger_radius_covers_more_and_t0_is_full(hopper_tiny_dataset: Path, capsys):
    rows = coverage_rows(hopper_tiny_dataset, 3, [0.6, 0.8], [0.0, 0.25])
    assert rows and all(r["r0.8"] >= r["r0.6"] for r in rows)
    assert all(r["r0.6"] == 1.0 and r["remaining"] == 1.0 for r in rows if r["t"] == 0.0)
    assert main([f"dataset={hopper_tiny_dataset}", "runs=2", "times=[0.25]"]) == 0
    assert "mean (occupied - not exited)" in capsys.readouterr().out
