import lightning as L
import pytest
import torch
from omegaconf import OmegaConf
from torch_geometric.loader import DataLoader

from neuraldem.errors import ConfigError
from neuraldem.gns.datamodule import GnsDataModule
from neuraldem.gns.module import GnsModule
from neuraldem.paths import config_dir


def tiny_module(dm, **net_overrides):
    cfg = OmegaConf.load(config_dir() / "model" / "gns_tiny.yaml")
    return GnsModule(OmegaConf.merge(cfg.net, net_overrides), datamodule=dm, optimizer=cfg.optimizer,
                     scheduler=cfg.scheduler)


@pytest.mark.solver
@pytest.mark.parametrize("name", ["hopper_tiny", "fb_tiny"])
def test_a_tiny_gns_learns(name, request):
    """A few optimizer steps on a fixed batch lower the one-step loss (the module trains at all)."""
    torch.manual_seed(0)
    dm = GnsDataModule(str(request.getfixturevalue(f"{name}_dataset")), name, history=2, noise_std=0.0)
    module = tiny_module(dm)
    assert module.net.n_scalars == len(dm.conditioning) and module.net.history == 2
    assert module.net.n_extra_walls == (2 if name == "hopper_tiny" else 0)
    batch = next(iter(DataLoader(dm.datasets["train"], batch_size=2)))
    opt = torch.optim.Adam(module.parameters(), lr=3e-3)
    losses = []
    for _ in range(30):
        loss = module.losses(batch)["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss))
    assert losses[-1] < 0.7 * losses[0], losses


@pytest.mark.solver
def test_trainer_fit_and_checkpoint_round_trip(fb_tiny_dataset, tmp_path):
    torch.manual_seed(0)
    dm = GnsDataModule(str(fb_tiny_dataset), "fb_tiny", history=2, noise_std=0.05)
    module = tiny_module(dm)
    trainer = L.Trainer(max_steps=3, accelerator="cpu", logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False)
    trainer.fit(module, datamodule=dm)
    trainer.save_checkpoint(tmp_path / "gns.ckpt")
    loaded = GnsModule.load_from_checkpoint(tmp_path / "gns.ckpt")
    batch = next(iter(DataLoader(dm.datasets["test"], batch_size=2)))
    torch.testing.assert_close(loaded.eval()(batch), module.eval()(batch))
    assert loaded.metadata["train_velocities"] == module.metadata["train_velocities"]


@pytest.mark.solver
def test_history_set_twice_is_refused(hopper_tiny_dataset):
    dm = GnsDataModule(str(hopper_tiny_dataset), "hopper_tiny", history=2)
    with pytest.raises(ConfigError, match="model.net.history=4 is invalid: it is set by data.datamodule.history"):
        tiny_module(dm, history=4)


@pytest.mark.solver
def test_bad_optimizer_name_ends_in_one_line(hopper_tiny_dataset):
    dm = GnsDataModule(str(hopper_tiny_dataset), "hopper_tiny", history=2)
    cfg = OmegaConf.load(config_dir() / "model" / "gns_tiny.yaml")
    with pytest.raises(ConfigError, match="model.optimizer.name='sgd'") as err:
        GnsModule(cfg.net, datamodule=dm, optimizer={"name": "sgd"})
    assert "\n" not in str(err.value)
