"""Rollout validation: ground truth scores zero, a divergence is penalised, and in a real Lightning fit the
callback logs its metrics at every validation and ModelCheckpoint keeps the checkpoint it scores best."""

from __future__ import annotations

import math
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch

from neuraldem.data.manifest import Manifest
from neuraldem.errors import ConfigError
from neuraldem.models.registry import net_config
from neuraldem.scenes.fluidized_bed.analysis.evaluation import FieldSeries
from neuraldem.scenes.fluidized_bed.dataset.report import metric_settings
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.datamodule import BedDataModule
from neuraldem.scenes.fluidized_bed.surrogate.module import BedModule
from neuraldem.scenes.fluidized_bed.surrogate.rollout_validation import (
    DIVERGENCE_PENALTY,
    RolloutValidation,
    score_pooled,
    score_rollout,
)
from tests.helpers import with_split

pytestmark = pytest.mark.solver


def test_ground_truth_scores_zero_and_a_changed_field_does_not(fb_tiny_dataset: Path):
    m = Manifest.load(fb_tiny_dataset)
    with BedFile(fb_tiny_dataset / str(m.record("sim_0000").file)) as f:
        truth = FieldSeries.from_dataset_file(f)
    settings = metric_settings(m)
    exact = score_rollout(truth, truth, settings, diverged=False)
    assert exact == {"sf_mean_rel_l2": 0.0, "sf_std_rel_l2": 0.0, "lacey_mae": 0.0,
                     "mass_drift": pytest.approx(exact["mass_drift"]), "score": pytest.approx(exact["mass_drift"])}
    assert exact["mass_drift"] < 1e-4  # the data conserves its solid volume
    lost = FieldSeries(truth.times, truth.solid_fraction * np.linspace(1.0, 0.9, len(truth.times))[:, None, None, None],
                       truth.fluid_velocity, truth.mixing, truth.grid, truth.particle_volume,
                       truth.total_particle_volume)  # 10 % of the solid disappears over the trajectory
    worse = score_rollout(lost, truth, settings, diverged=False)
    assert worse["mass_drift"] == pytest.approx(0.1, rel=1e-6) and worse["sf_mean_rel_l2"] > 0
    assert worse["score"] == pytest.approx(sum(worse[k] for k in ("sf_mean_rel_l2", "sf_std_rel_l2", "lacey_mae",
                                                                  "mass_drift")))
    assert score_rollout(truth, truth, settings, diverged=True)["score"] >= DIVERGENCE_PENALTY
    # the pooled reference of one run is that run; of both packings it differs from either
    assert score_pooled(truth, [truth], settings, ["sim_0000"], diverged=False) == exact
    with BedFile(fb_tiny_dataset / str(m.record("sim_0001").file)) as f:
        twin = FieldSeries.from_dataset_file(f)
    both = score_pooled(truth, [truth, twin], settings, ["sim_0000", "sim_0001"], diverged=False)
    assert both["sf_std_rel_l2"] > 0 and both["mass_drift"] == exact["mass_drift"]


@pytest.fixture
def fb_tiny_with_val(fb_tiny_dataset: Path, tmp_path: Path) -> Path:
    """fb_tiny whose held-out velocity also serves as the validation part (fb_tiny itself has none)."""
    return with_split(fb_tiny_dataset, tmp_path / "fb_tiny", "velocity", "val", ids_of="test")


def test_callback_logs_at_every_validation_and_picks_the_checkpoint(fb_tiny_with_val: Path, tmp_path: Path):
    torch.manual_seed(0)
    dm = BedDataModule(str(fb_tiny_with_val), "fb_tiny", batch_size=2)
    module = BedModule(net_config("fb_tiny"), datamodule=dm)
    seen: list[float] = []

    class Record(L.Callback):
        def on_validation_end(self, trainer, pl_module):
            seen.append(float(trainer.callback_metrics["val/rollout_score"]))

    ckpt = L.pytorch.callbacks.ModelCheckpoint(dirpath=tmp_path / "ckpt", monitor="val/rollout_score", mode="min",
                                               save_top_k=1, filename="step{step}", auto_insert_metric_name=False)
    trainer = L.Trainer(max_steps=6, val_check_interval=2, check_val_every_n_epoch=None, accelerator="cpu",
                        logger=False, enable_progress_bar=False, enable_model_summary=False, num_sanity_val_steps=0,
                        callbacks=[RolloutValidation(steps=5), Record(), ckpt])
    trainer.fit(module, datamodule=dm)
    assert len(seen) == 3 and all(math.isfinite(s) and s > 0 for s in seen)
    for key in ("sf_mean_rel_l2", "sf_std_rel_l2", "lacey_mae", "mass_drift"):
        assert math.isfinite(float(trainer.callback_metrics[f"val/rollout_{key}"]))
    assert float(ckpt.best_model_score) == pytest.approx(min(seen))
    assert module.training  # the rollouts put the net in eval mode; training goes on in train mode


def test_pooled_reference_rolls_out_beyond_the_trajectory(fb_tiny_with_val: Path, caplog):
    """reference=pooled: 30 steps from an fb_tiny trajectory of 20, scored against the velocity's runs."""
    torch.manual_seed(0)
    dm = BedDataModule(str(fb_tiny_with_val), "fb_tiny", batch_size=2)
    module = BedModule(net_config("fb_tiny"), datamodule=dm)
    trainer = L.Trainer(max_steps=2, val_check_interval=2, check_val_every_n_epoch=None, accelerator="cpu",
                        logger=False, enable_progress_bar=False, enable_model_summary=False, num_sanity_val_steps=0,
                        enable_checkpointing=False, callbacks=[RolloutValidation(steps=30, reference="pooled")])
    with caplog.at_level("INFO", logger="neuraldem.scenes.fluidized_bed.surrogate.rollout_validation"):
        trainer.fit(module, datamodule=dm)
    assert "(1 velocities, 30 steps)" in caplog.text
    assert math.isfinite(float(trainer.callback_metrics["val/rollout_score"]))


def test_bad_settings_and_the_wrong_datamodule_say_so():
    with pytest.raises(ConfigError, match="callbacks.rollout_validation.reference"):
        RolloutValidation(reference="long")
    with pytest.raises(ConfigError, match="callbacks.rollout_validation.steps"):
        RolloutValidation(steps=0)
    with pytest.raises(ConfigError, match="callbacks.rollout_validation.part"):
        RolloutValidation(part="train")

    class Trainer:
        sanity_checking = False
        datamodule = object()

    with pytest.raises(ConfigError, match="fluidized-bed datamodule"):
        RolloutValidation().on_validation_epoch_end(Trainer(), None)  # type: ignore[arg-type]
