"""Every experiment composes, and its datamodule, model and trainer build (nothing is run)."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import pytest
from hydra.utils import instantiate

from neuraldem.config.build import build_callbacks, build_trainer
from neuraldem.paths import config_dir

EXPERIMENTS = sorted(p.stem for p in (config_dir() / "experiment").glob("*.yaml"))


def test_there_are_experiments():
    assert {"hopper_quickstart", "hopper_micro", "hopper_macro"} <= set(EXPERIMENTS)


@pytest.mark.solver
@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_experiment_builds(experiment: str, compose_train_cfg, hopper_tiny_dataset: Path):
    # the tiny real dataset stands in for each experiment's own (built from the same pipeline)
    cfg = compose_train_cfg(f"experiment={experiment}", f"data.dataset_dir={hopper_tiny_dataset}",
                            "data.name=hopper_tiny")
    assert cfg.task_name == experiment
    dm = instantiate(cfg.data.datamodule)
    module = instantiate(cfg.model, datamodule=dm, _recursive_=False)
    assert isinstance(module, L.LightningModule)
    assert module.net.n_scalars == len(cfg.data.conditioning)
    trainer = build_trainer(cfg.trainer, callbacks=build_callbacks(cfg.callbacks), loggers=[])
    assert trainer.max_steps == cfg.trainer.max_steps


@pytest.mark.parametrize("split", ["random", "band"])
def test_ablation_grid_composes(split: str, compose_train_cfg):
    for experiment in ("hopper_micro", "hopper_theta", "hopper_ffc", "hopper_macro", "hopper_all"):
        cfg = compose_train_cfg(f"experiment={experiment}", f"data.split={split}")
        assert cfg.data.datamodule.split == split and cfg.evaluate
