"""The cross-validated Table 4: baselines and a field model scored on the same held-out runs of a real tiny
LIGGGHTS dataset; too few runs say so in one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.scenes.hopper.analysis import cv as hopper_cv

pytestmark = pytest.mark.solver


def test_baselines_on_every_fold(hopper_tiny_dataset: Path, tmp_path: Path):
    out = tmp_path / "table.md"
    assert hopper_cv.main([f"dataset={hopper_tiny_dataset}", "n_folds=2", "splits=[random]", f"out={out}"]) == 0
    result = json.loads(out.with_suffix(".json").read_text())
    folds = [f for f in result["folds"] if f["row"] == "micro"]
    assert len(folds) == 2
    tested = sorted(i for f in folds for i in f["test_ids"])
    assert len(tested) == len(set(tested)) == result["n_usable"]  # every run held out exactly once
    summary = result["summary"]["random"]["micro"]
    assert set(summary) == {"constant", "gp"}
    assert summary["gp"]["n_folds"] == 2 and "drainage t95" in out.read_text()


def test_field_model_fold_is_scored_beside_baselines_fitted_on_its_runs(hopper_tiny_dataset: Path, tmp_path: Path):
    from neuraldem.models.registry import net_config
    from neuraldem.scenes.hopper.analysis.evaluation import evaluate_checkpoint
    from neuraldem.scenes.hopper.surrogate.datamodule import HopperDataModule
    from neuraldem.scenes.hopper.surrogate.module import HopperModule
    from tests.conftest import train_briefly

    dm = HopperDataModule(str(hopper_tiny_dataset), "hopper_tiny", ["t", "alpha", "mu_s", "mu_r"], n_queries=32,
                          fold=1, n_folds=2)
    ckpt = train_briefly(HopperModule(net_config("hopper_tiny"), datamodule=dm), dm, tmp_path / "f1.ckpt")
    run = tmp_path / "grid" / "hopper_micro-random-f1"
    evaluate_checkpoint(ckpt, run / "evaluation", tmp_path, dataset_dir=hopper_tiny_dataset, vtk=False,
                        progress=False)
    out = tmp_path / "table.md"
    hopper_cv.main([f"grids=[{tmp_path / 'grid'}]", f"dataset={hopper_tiny_dataset}", "n_folds=2", "splits=[random]",
                    f"out={out}"])
    result = json.loads(out.with_suffix(".json").read_text())
    fold = next(f for f in result["folds"] if f["row"] == "micro" and f["fold"] == 1)
    assert fold["test_ids"] == dm.split_ids["test"]
    assert set(fold["methods"]) == {"constant", "gp", "field model"}
    assert fold["methods"]["gp"]["n_train"] == len(dm.split_ids["train"]) + len(dm.split_ids["val"])
    row = next(line for line in out.read_text().splitlines() if line.startswith("| micro | field model | 1 ("))
    assert "+-" not in row  # one fold has no spread to show (not "+- 0.00")
    assert "+-" in next(line for line in out.read_text().splitlines() if line.startswith("| micro | gp | 2 ("))


def test_too_few_runs_for_five_folds_is_one_line(hopper_tiny_dataset: Path, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]):
    with pytest.raises(SystemExit) as exit_info:
        hopper_cv.main([f"dataset={hopper_tiny_dataset}", f"out={tmp_path / 't.md'}"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "too few for 5-fold" in err and "generate more with neuraldem datagen" in err and "\n" not in err
