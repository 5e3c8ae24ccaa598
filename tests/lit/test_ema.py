"""`neuraldem.lit.ema.Ema` (callbacks.ema): bad values refused with the key, and the average is a pure shadow:
the training weights of a run with it are bit-identical to a run without it (so a with/without comparison
is paired), while the checkpoint's state_dict holds the average."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from neuraldem.errors import ConfigError
from neuraldem.lit.ema import Ema


@pytest.mark.parametrize("kwargs,key", [({"decay": 1.0}, "callbacks.ema.decay"), ({"decay": 0}, "callbacks.ema.decay"),
                                        ({"update_starting_at_step": -1}, "callbacks.ema.update_starting_at_step"),
                                        ({"update_every_n_steps": 0}, "callbacks.ema.update_every_n_steps")])
def test_bad_values_are_refused_with_their_key(kwargs: dict, key: str):
    with pytest.raises(ConfigError, match=key):
        Ema(**kwargs)


def _train(dataset: Path, folder: Path, ema: bool) -> dict:
    import lightning as L
    from lightning.pytorch.callbacks import ModelCheckpoint

    from neuraldem.models.registry import net_config
    from neuraldem.scenes.fluidized_bed.surrogate.datamodule import BedDataModule
    from neuraldem.scenes.fluidized_bed.surrogate.module import BedModule

    L.seed_everything(0)
    dm = BedDataModule(str(dataset), "fb_tiny", batch_size=2)
    module = BedModule(net_config("fb_tiny"), datamodule=dm)
    save = ModelCheckpoint(dirpath=folder, filename="step", every_n_train_steps=4, save_top_k=-1, monitor=None)
    callbacks = [Ema(decay=0.5, update_starting_at_step=1), save] if ema else [save]
    trainer = L.Trainer(max_steps=4, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, limit_val_batches=0, callbacks=callbacks, deterministic=True)
    trainer.fit(module, datamodule=dm)
    return torch.load(folder / "step.ckpt", map_location="cpu", weights_only=False)


@pytest.mark.solver
def test_the_average_does_not_change_training(fb_tiny_dataset: Path, tmp_path: Path):
    plain = _train(fb_tiny_dataset, tmp_path / "plain", ema=False)
    averaged = _train(fb_tiny_dataset, tmp_path / "ema", ema=True)
    net = [k for k in plain["state_dict"] if k.startswith("net.")]
    for k in net:  # the optimizer's weights: identical with and without the average
        assert torch.equal(plain["state_dict"][k], averaged["current_model_state"][k]), k
    # the checkpoint's weights are the average, which lags the optimizer's
    assert any(not torch.equal(plain["state_dict"][k], averaged["state_dict"][k]) for k in net)
