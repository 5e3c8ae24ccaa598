"""Dataset report on the tiny real dataset: numbers agree with the manifest, figures are written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.data.manifest import Manifest
from neuraldem.eval.dataset_report import main

pytestmark = pytest.mark.solver


def test_report(hopper_tiny_dataset: Path, tmp_path: Path):
    assert main([f"dataset={hopper_tiny_dataset}", f"out={tmp_path}"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    m = Manifest.load(hopper_tiny_dataset)
    drain = [r.metrics["drainage_time"] for r in m.usable()]
    assert summary["metrics"]["drainage_time"]["max"] == max(drain)
    assert summary["status"]["ok"] == len(m.usable())
    assert summary["cpu_s_per_characterization"]["n"] == len(m.usable())
    assert (tmp_path / "metrics_over_parameters.png").stat().st_size > 10_000
    assert (tmp_path / "characterization.png").stat().st_size > 10_000


def test_refill_report_has_the_refill_metrics(hopper_refill_tiny_dataset: Path, tmp_path: Path):
    assert main([f"dataset={hopper_refill_tiny_dataset}", f"out={tmp_path}"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    m = Manifest.load(hopper_refill_tiny_dataset)
    medians = [r.metrics["exit_residence_median"] for r in m.usable()]
    assert summary["metrics"]["exit_residence_median"]["max"] == max(medians)
    assert "drainage_time" not in summary["metrics"] and summary["flow_regimes"] == {}  # a refill never drains
    assert (tmp_path / "metrics_over_parameters.png").stat().st_size > 10_000
