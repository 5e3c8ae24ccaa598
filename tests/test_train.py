"""`neuraldem train` as a user meets it: help, printed config, and bad input in one clear line."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers import run_module


def _one_clear_error(proc) -> str:
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0, out
    assert "Traceback" not in out, out
    return out


def test_help_lists_groups():
    proc = run_module("neuraldem", "train", "--help")
    assert proc.returncode == 0
    for group in ("data:", "model:", "trainer:", "logger:", "experiment"):
        assert group in proc.stdout


def test_cfg_job_prints_composed_config(tmp_path: Path):
    proc = run_module("neuraldem", "train", "--cfg", "job", env={"NEURALDEM_DATA": str(tmp_path)})
    assert proc.returncode == 0, proc.stderr
    assert "trainer:" in proc.stdout and "_target_: lightning.pytorch.Trainer" in proc.stdout


def test_missing_dataset_says_how_to_generate(tmp_path: Path):
    proc = run_module("neuraldem", "train", "data=hopper_tiny", env={"NEURALDEM_DATA": str(tmp_path)})
    out = _one_clear_error(proc)
    assert f"no dataset at {tmp_path}/datasets/hopper_tiny" in out
    assert "neuraldem datagen data=hopper_tiny" in out


def test_unknown_experiment(tmp_path: Path):
    out = _one_clear_error(run_module("neuraldem", "train", "experiment=no_such_thing",
                                      env={"NEURALDEM_DATA": str(tmp_path)}))
    assert "no experiment config 'no_such_thing': searched" in out and "hopper_micro" in out  # before Hydra composes


def test_negative_trainer_value(tmp_path: Path):
    out = _one_clear_error(run_module("neuraldem", "train", "trainer.max_steps=-5",
                                      env={"NEURALDEM_DATA": str(tmp_path)}))
    assert "trainer.max_steps=-5 is invalid" in out


def test_a_bad_net_value_fails_before_any_data_is_read(tmp_path: Path):
    """The net's schema is checked when the config is composed: no dataset here, and the net is what is named."""
    out = _one_clear_error(run_module("neuraldem", "train", "experiment=fb_quick", "model.net.num_heads=5",
                                      env={"NEURALDEM_DATA": str(tmp_path)}))
    assert "model.net.num_heads=5 is invalid: must divide model.net.dim=" in out and "no dataset" not in out


def test_typo_in_key(tmp_path: Path):
    out = _one_clear_error(run_module("neuraldem", "train", "trainr.max_steps=5",
                                      env={"NEURALDEM_DATA": str(tmp_path)}))
    assert "trainr" in out


def test_training_without_any_logger(hopper_tiny_dataset: Path, tmp_path: Path):
    """logger=none must train: callbacks that only feed a logger (the LR monitor) are dropped, not fatal."""
    proc = run_module("neuraldem", "train", "experiment=hopper_quickstart", "logger=none", "evaluate=false",
                      "trainer.max_steps=2", "trainer.val_check_interval=2", f"data.dataset_dir={hopper_tiny_dataset}",
                      f"hydra.run.dir={tmp_path}/run", env={"NEURALDEM_DATA": str(tmp_path)})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert (tmp_path / "run" / "checkpoints" / "last.ckpt").is_file()


@pytest.mark.solver
@pytest.mark.parametrize("scene", ["hopper", "fb"])
def test_gns_experiments_train(scene: str, request: pytest.FixtureRequest, tmp_path: Path):
    """`experiment=gns_<scene>_tiny` trains the particle baseline through the same entry point."""
    dataset = request.getfixturevalue(f"{'hopper' if scene == 'hopper' else 'fb'}_tiny_dataset")
    proc = run_module("neuraldem", "train", f"experiment=gns_{scene}_tiny", "logger=none", "trainer.max_steps=2",
                      "trainer.val_check_interval=2", f"data.dataset_dir={dataset}", f"hydra.run.dir={tmp_path}/run",
                      env={"NEURALDEM_DATA": str(tmp_path)})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert (tmp_path / "run" / "checkpoints" / "last.ckpt").is_file()


@pytest.mark.solver
def test_gns_bad_value_is_one_line(hopper_tiny_dataset: Path, tmp_path: Path):
    out = _one_clear_error(run_module("neuraldem", "train", "experiment=gns_hopper_tiny", "logger=none",
                                      "data.datamodule.noise_std=5", f"data.dataset_dir={hopper_tiny_dataset}",
                                      f"hydra.run.dir={tmp_path}/run", env={"NEURALDEM_DATA": str(tmp_path)}))
    assert "data.datamodule.noise_std=5 is invalid" in out


def test_latest_checkpoint_is_the_newest_state_last_is_the_kept_one(hopper_tiny_dataset: Path, tmp_path: Path):
    """Lightning's last.ckpt copies the newest KEPT checkpoint (the selected model); latest.ckpt must hold the
    newest training state (what a killed run resumes from and what "the final model" means)."""
    import torch

    proc = run_module("neuraldem", "train", "experiment=hopper_quickstart", "logger=none", "evaluate=false",
                      "trainer.max_steps=4", "trainer.val_check_interval=2", f"data.dataset_dir={hopper_tiny_dataset}",
                      f"hydra.run.dir={tmp_path}/run", env={"NEURALDEM_DATA": str(tmp_path)})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    ckpts = tmp_path / "run" / "checkpoints"
    step = {p.name: torch.load(p, map_location="cpu", weights_only=False)["global_step"] for p in ckpts.glob("*.ckpt")}
    assert step["latest.ckpt"] == 4, step
    kept = [name for name in step if name.startswith("step")]
    assert len(kept) == 1 and step["last.ckpt"] == step[kept[0]], step


@pytest.mark.parametrize("damage", ["missing", "truncated"])
def test_a_bad_resume_checkpoint_is_one_line_before_any_data_is_read(damage: str, tmp_path: Path):
    ckpt = tmp_path / "latest.ckpt"
    if damage == "truncated":
        ckpt.write_bytes(b"PK\x03\x04" + bytes(100))  # the start of a zip archive, cut off
    out = _one_clear_error(run_module("neuraldem", "train", "experiment=hopper_quickstart", f"ckpt_path={ckpt}",
                                      env={"NEURALDEM_DATA": str(tmp_path)}))
    assert f"config value ckpt_path={ckpt} is invalid" in out
    assert ("does not exist" if damage == "missing" else "not a readable checkpoint") in out
    assert "checkpoints/latest.ckpt" in out and "no dataset" not in out


def test_resuming_with_another_net_names_the_differing_keys(tiny_checkpoint: Path, tmp_path: Path):
    out = _one_clear_error(run_module("neuraldem", "train", "experiment=hopper_quickstart", "model.net.dim=64",
                                      f"ckpt_path={tiny_checkpoint}", env={"NEURALDEM_DATA": str(tmp_path)}))
    assert "its net differs from model.net in dim" in out


def test_resuming_a_bed_run_ignores_the_channels_its_data_set(compose_train_cfg, tmp_path: Path):
    """experiment=fb's module sets model.net.fluid_channels from its dataset (7 with the solids flux), so the
    checkpoint holds 7 where the config says 4: not a different net (a killed fb run must resume); dim still is."""
    import torch
    from omegaconf import OmegaConf

    from neuraldem.errors import ConfigError
    from neuraldem.train import check_resume_checkpoint

    cfg = OmegaConf.merge(compose_train_cfg("experiment=fb"), {"ckpt_path": str(tmp_path / "latest.ckpt")})
    net = OmegaConf.to_container(cfg.model.net, resolve=True)
    metadata = {"kind": "fluidized_bed", "data_name": "fb_small"}
    for changed, refused in (({"fluid_channels": 7}, False), ({"fluid_channels": 7, "dim": 2 * net["dim"]}, True)):
        torch.save({"hyper_parameters": {"net": {**net, **changed}, "metadata": metadata}, "state_dict": {}},
                   tmp_path / "latest.ckpt")
        if refused:
            with pytest.raises(ConfigError, match="differs from model.net in dim"):
                check_resume_checkpoint(cfg)
        else:
            check_resume_checkpoint(cfg)
