"""Benchmark test fixtures: evaluated run folders made from the tiny checkpoint on the real tiny dataset."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from omegaconf import OmegaConf


def make_run(root: Path, name: str, ckpt: Path, dataset: Path, n_queries: int = 32) -> Path:
    """A run folder as `neuraldem.train evaluate=true` leaves it: checkpoints/, evaluation/, .hydra/."""
    from neuraldem.eval.hopper_report import evaluate_checkpoint

    run = root / name
    (run / "checkpoints").mkdir(parents=True)
    shutil.copy2(ckpt, run / "checkpoints" / "last.ckpt")
    (run / ".hydra").mkdir()
    OmegaConf.save({"data": {"datamodule": {"n_queries": n_queries}}}, run / ".hydra" / "config.yaml")
    evaluate_checkpoint(run / "checkpoints" / "last.ckpt", run / "evaluation", root, dataset_dir=dataset,
                        vtk=False, progress=False)
    return run


@pytest.fixture(scope="session")
def evaluated_runs(tiny_checkpoint: Path, hopper_tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with one evaluated run and a copy of it under a sweep sub-folder (`multirun/0`)."""
    root = tmp_path_factory.mktemp("runs")
    run = make_run(root, "tiny", tiny_checkpoint, hopper_tiny_dataset)
    shutil.copytree(run, root / "multirun" / "0")
    return root
