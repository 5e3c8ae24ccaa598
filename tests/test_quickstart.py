"""README command 1's main job, end to end on the real solver: datagen -> train -> evaluate -> plots."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.helpers import run_module

pytestmark = pytest.mark.solver


def test_hopper_quickstart_end_to_end(hopper_tiny_dataset: Path, data_root: Path, tmp_path: Path):
    # the dataset fixture made data=hopper_tiny in data_root; datagen finds it finished and returns at once
    env = {"NEURALDEM_DATA": str(data_root)}
    gen = run_module("neuraldem", "datagen", "data=hopper_tiny", "n_sims=8", "progress=false", env=env)
    assert gen.returncode == 0, gen.stderr
    assert "8 finished, 0 to run" in gen.stdout + gen.stderr
    proc = run_module("neuraldem", "train", "experiment=hopper_quickstart", "trainer.max_steps=60",
                      "trainer.val_check_interval=30", f"hydra.run.dir={tmp_path}/run", env=env, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "| drainage t95 [% of mean] |" in proc.stdout
    assert "| field model |" in proc.stdout and "| gp |" in proc.stdout  # the baselines beside the model
    run = tmp_path / "run"  # its own folder: the data root may hold runs of earlier sessions
    ev = run / "evaluation"
    metrics = json.loads((ev / "metrics.json").read_text())
    assert metrics["aggregate"]["n_sims"] >= 1 and metrics["conditioning"] == ["t", "alpha", "mu_s", "mu_r"]
    for png in ("predicted_vs_dem.png", "stripes.png", "residence_slice.png"):
        assert (ev / png).stat().st_size > 10_000
    assert list((ev / "vtk").glob("*.pvd"))
    assert (run / "checkpoints" / "last.ckpt").exists()
