"""What a release reads of the training run: its overrides (the recipe) for a checkpoint kept among the run's
periodic ones as well as for its last one, and the checkpoint's path inside the run for the rebuild command."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.pretrained.building import in_run, recipe_of, run_folder


@pytest.mark.parametrize("inside", ["checkpoints/last.ckpt", "checkpoints/all/step008000.ckpt"])
def test_a_checkpoint_finds_its_run_and_recipe(tmp_path: Path, inside: str):
    run = tmp_path / "runs" / "fb_seed0"
    (run / ".hydra").mkdir(parents=True)
    (run / ".hydra" / "overrides.yaml").write_text(json.dumps(["experiment=fb", "seed=0", "trainer=cpu",
                                                               "model.net.dim=48"]))
    ckpt = run / inside
    assert run_folder(ckpt) == run and in_run(ckpt) == inside
    assert recipe_of(ckpt) == ("fb", ["experiment=fb", "model.net.dim=48"])


def test_a_checkpoint_outside_a_run_has_no_recipe(tmp_path: Path):
    ckpt = tmp_path / "chosen" / "selected.ckpt"  # a copy outside its run (fb-select's)
    assert run_folder(ckpt) is None and in_run(ckpt) == "checkpoints/selected.ckpt"
    assert recipe_of(ckpt) == ("custom", [])
