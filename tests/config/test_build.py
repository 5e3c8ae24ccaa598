"""The trainer has exactly the progress bar the config asks for: `callbacks.progress` (or none when it is null
or when `trainer.enable_progress_bar=false`), never Lightning's default one filling background logs."""

from __future__ import annotations

from lightning.pytorch.callbacks import TQDMProgressBar
from omegaconf import OmegaConf

from neuraldem.config.build import build_trainer

TRAINER = {"_target_": "lightning.pytorch.Trainer", "accelerator": "cpu", "devices": 1, "max_steps": 1,
           "logger": False, "enable_checkpointing": False}


def test_no_progress_callback_means_no_bar(tmp_path):
    trainer = build_trainer(OmegaConf.create({**TRAINER, "default_root_dir": str(tmp_path)}), [], [])
    assert trainer.progress_bar_callback is None


def test_the_configured_bar_is_used(tmp_path):
    bar = TQDMProgressBar(refresh_rate=5)
    trainer = build_trainer(OmegaConf.create({**TRAINER, "default_root_dir": str(tmp_path)}), [bar], [])
    assert trainer.progress_bar_callback is bar


def test_trainer_switch_wins_over_the_callback(tmp_path):
    cfg = OmegaConf.create({**TRAINER, "default_root_dir": str(tmp_path), "enable_progress_bar": False})
    trainer = build_trainer(cfg, [TQDMProgressBar()], [])
    assert trainer.progress_bar_callback is None


def test_checkpoint_on_rollout_metrics_needs_the_rollout_callback(tmp_path):
    from neuraldem.config.build import build_callbacks
    from neuraldem.errors import ConfigError

    ckpt = {"_target_": "lightning.pytorch.callbacks.ModelCheckpoint", "dirpath": str(tmp_path),
            "monitor": "val/rollout_score"}
    rollout = {"_target_": "neuraldem.scenes.fluidized_bed.surrogate.rollout_validation.RolloutValidation", "steps": 10}
    built = build_callbacks(OmegaConf.create({"checkpoint": ckpt, "rollout_validation": rollout}))
    assert [type(cb).__name__ for cb in built] == ["ModelCheckpoint", "RolloutValidation"]
    import pytest

    with pytest.raises(ConfigError, match="callbacks.checkpoint.monitor=val/rollout_score .*val/loss"):
        build_callbacks(OmegaConf.create({"checkpoint": ckpt, "rollout_validation": None}))
    build_callbacks(OmegaConf.create({"checkpoint": {**ckpt, "monitor": "val/loss"}}))  # one-step loss: fine


def test_checkpoints_are_written_whole_or_not_at_all(tmp_path, monkeypatch):
    """A save that dies half-way leaves the previous checkpoint as it was and no temporary file."""
    import pytest
    import torch
    from lightning.pytorch.plugins.io import TorchCheckpointIO

    from neuraldem.config.build import AtomicCheckpointIO

    trainer = build_trainer(OmegaConf.create({**TRAINER, "default_root_dir": str(tmp_path)}), [], [])
    io = trainer.strategy.checkpoint_io
    assert isinstance(io, AtomicCheckpointIO)
    path = tmp_path / "ckpt" / "latest.ckpt"
    io.save_checkpoint({"global_step": 4}, path)
    assert torch.load(path, weights_only=False)["global_step"] == 4

    def dies_half_way(self, checkpoint, p, storage_options=None):
        p.write_bytes(b"PK\x03\x04 half")  # what a kill mid-write leaves
        raise KeyboardInterrupt

    monkeypatch.setattr(TorchCheckpointIO, "save_checkpoint", dies_half_way)
    with pytest.raises(KeyboardInterrupt):
        io.save_checkpoint({"global_step": 6}, path)
    assert torch.load(path, weights_only=False)["global_step"] == 4
    assert sorted(q.name for q in path.parent.iterdir()) == ["latest.ckpt"]
