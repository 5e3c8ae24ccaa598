"""The practitioner validation callback: its scores on cases with known answers, and that a training run
logs them and keeps the checkpoint they pick (real tiny LIGGGHTS dataset)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neuraldem.errors import ConfigError
from neuraldem.scenes.hopper.surrogate.predictors import TrajectoryFields
from neuraldem.scenes.hopper.surrogate.validation import PractitionerValidation, count_bias, practitioner_score


def _fields(occ: np.ndarray) -> TrajectoryFields:
    t = np.arange(len(occ)) * 0.1
    return TrajectoryFields(t, occ, np.zeros((*occ.shape, 3)), np.zeros(occ.shape))


def test_count_bias_known_answer():
    truth = _fields(np.array([[1.0, 1.0, 1.0, 1.0], [1.0, 1.0, 0.0, 0.0]]))
    pred = _fields(np.array([[1.0, 1.0, 1.0, 1.0], [1.0, 1.0, 0.5, 0.5]]))  # +1 point of 4 at t = 0.1
    signed, absolute = count_bias(truth, pred)
    assert signed == pytest.approx(0.125) and absolute == pytest.approx(0.125)


def test_score_is_errors_in_units_of_their_targets():
    agg = {"drainage_t95_pct_of_mean": 8.0, "residual_mae_pp": 0.4, "outflow_rel_err_pct": 5.0}
    assert practitioner_score(agg, {"drainage_t95_pct_of_mean": 4.0, "residual_mae_pp": 0.8,
                                    "outflow_rel_err_pct": 2.5}) == pytest.approx(2 + 0.5 + 2)
    agg["outflow_rel_err_pct"] = float("nan")
    assert practitioner_score(agg, {"outflow_rel_err_pct": 2.5}) == 10.0


def test_bad_settings_name_the_key():
    with pytest.raises(ConfigError, match=r"callbacks\.practitioner_validation\.max_points"):
        PractitionerValidation(max_points=0)
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['drainage'\]"):
        PractitionerValidation(scales={"drainage": 1.0})


@pytest.mark.solver
def test_training_logs_the_scores_and_checkpoints_by_them(hopper_tiny_dataset: Path, tmp_path: Path):
    import lightning as L
    from lightning.pytorch.callbacks import ModelCheckpoint

    from neuraldem.models.registry import net_config
    from neuraldem.scenes.hopper.surrogate.datamodule import HopperDataModule
    from neuraldem.scenes.hopper.surrogate.module import HopperModule

    dm = HopperDataModule(str(hopper_tiny_dataset), "hopper_tiny", ["t", "alpha", "mu_s", "mu_r"], n_queries=32,
                          batch_size=2)
    ckpt = ModelCheckpoint(dirpath=tmp_path, monitor="val/practitioner_score", mode="min", save_top_k=1)
    trainer = L.Trainer(max_steps=4, val_check_interval=2, limit_val_batches=1, accelerator="cpu", logger=False,
                        callbacks=[PractitionerValidation(max_points=100, time_stride=4), ckpt],
                        enable_progress_bar=False, enable_model_summary=False, num_sanity_val_steps=0)
    trainer.fit(HopperModule(net_config("hopper_tiny"), datamodule=dm), datamodule=dm)
    logged = trainer.callback_metrics
    for key in ("val/drainage_t95_pct", "val/residual_pp", "val/outflow_pct", "val/count_bias_pct",
                "val/practitioner_score"):
        assert key in logged and np.isfinite(float(logged[key])), key
    assert ckpt.best_model_path and ckpt.best_model_score is not None
