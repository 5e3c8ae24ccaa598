"""The fluidized-bed surrogate pipeline as a user runs it: train experiment=fb_quick -> rollouts -> evaluation."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.helpers import run_module

pytestmark = pytest.mark.solver


def test_fb_quick_trains_and_evaluates(fb_tiny_dataset: Path, tmp_path: Path):
    env = {"NEURALDEM_DATA": str(fb_tiny_dataset.parent.parent)}
    proc = run_module("neuraldem", "train", "experiment=fb_quick", "trainer.max_steps=10",
                      f"hydra.run.dir={tmp_path}", env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "Fluidized-bed surrogate vs CFD-DEM" in proc.stdout and "## Stability" in proc.stdout
    metrics = json.loads((tmp_path / "evaluation" / "metrics.json").read_text())
    assert metrics["rollout_steps"] == 200 and metrics["horizons"] == [1, 3, 10]
    assert metrics["checkpoint"].endswith("last.ckpt")  # fb_tiny has no validation part: the last checkpoint
    assert (tmp_path / "evaluation" / "time_averages_sim_0002.png").stat().st_size > 10_000
