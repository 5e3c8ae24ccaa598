"""`neuraldem.eval.current_weights`: the raw weights of a weight-averaged (EMA) checkpoint as a checkpoint of
their own, loadable by every tool, and a checkpoint without averaging refused."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from neuraldem.errors import DataError
from neuraldem.eval.checkpoints import read_checkpoint
from neuraldem.eval.current_weights import main, write_current_weights


@pytest.fixture(scope="module")
def ema_checkpoint(fb_tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """fb_tiny trained 4 steps with an EMA of decay 0.5, saved by a ModelCheckpoint during fit (as a training
    run saves it: averaged weights in state_dict, the optimizer's in current_model_state)."""
    import lightning as L
    from lightning.pytorch.callbacks import EMAWeightAveraging, ModelCheckpoint

    from neuraldem.models.registry import net_config
    from neuraldem.scenes.fluidized_bed.surrogate.datamodule import BedDataModule
    from neuraldem.scenes.fluidized_bed.surrogate.module import BedModule

    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("ema")
    dm = BedDataModule(str(fb_tiny_dataset), "fb_tiny", batch_size=2)
    module = BedModule(net_config("fb_tiny"), datamodule=dm)
    save = ModelCheckpoint(dirpath=folder, filename="ema", every_n_train_steps=4, save_top_k=-1, monitor=None)
    trainer = L.Trainer(max_steps=4, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, limit_val_batches=0,
                        callbacks=[EMAWeightAveraging(decay=0.5), save])
    trainer.fit(module, datamodule=dm)
    return folder / "ema.ckpt"


def net_weights(path: Path) -> dict[str, torch.Tensor]:
    module = read_checkpoint(path).module("fluidized_bed")
    return {k: v.detach().clone() for k, v in module.state_dict().items() if k.startswith("net.")}


def test_the_copy_holds_the_current_weights_and_loads(ema_checkpoint: Path, tmp_path: Path):
    raw = torch.load(ema_checkpoint, map_location="cpu", weights_only=False)
    assert "current_model_state" in raw
    out = write_current_weights(ema_checkpoint, tmp_path / "current.ckpt")
    averaged, current = net_weights(ema_checkpoint), net_weights(out)
    assert averaged.keys() == current.keys()
    for k, v in current.items():
        assert torch.equal(v, raw["current_model_state"][k]), k
    # 4 Lion steps with decay 0.5: the average lags the optimizer's weights
    assert any(not torch.equal(averaged[k], current[k]) for k in current)
    written = torch.load(out, map_location="cpu", weights_only=False)
    assert "current_model_state" not in written and "averaging_state" not in written
    assert written["hyper_parameters"]["metadata"] == raw["hyper_parameters"]["metadata"]


def test_a_checkpoint_without_averaging_is_refused(fb_tiny_checkpoint: Path, tmp_path: Path):
    with pytest.raises(DataError, match="not trained with weight averaging"):
        write_current_weights(fb_tiny_checkpoint, tmp_path / "x.ckpt")


def test_the_command_refuses_to_overwrite_its_input(ema_checkpoint: Path, capsys: pytest.CaptureFixture):
    with pytest.raises(SystemExit) as exit_info:
        main([str(ema_checkpoint), str(ema_checkpoint)])
    assert exit_info.value.code == 2
    assert "the checkpoint being read" in capsys.readouterr().err
