"""The GNS baseline trains from an export: the same samples as from the dataset (walls only as the box), the
training entry point with experiment=gns_export_tiny, and checkpoints the dataset rollouts refuse."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neuraldem.errors import ConfigError, DataError
from neuraldem.eval.checkpoints import read_checkpoint
from neuraldem.export.__main__ import export_dataset
from neuraldem.export.datamodule import ExportGnsDataModule
from neuraldem.gns.datamodule import GnsDataModule
from neuraldem.gns.rollout import load_gns_checkpoint
from tests.helpers import run_module


@pytest.fixture(scope="module")
def hopper_export(hopper_tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("export") / "hopper_gns"
    export_dataset("gns", hopper_tiny_dataset, out, exits="hold")
    return out


@pytest.mark.solver
def test_samples_match_the_datasets(hopper_export: Path, hopper_tiny_dataset: Path):
    """Held particles are absent again: the export's samples are the dataset's (float32 positions aside)."""
    ours = GnsDataModule(str(hopper_tiny_dataset), "hopper_tiny", history=2)
    ours.setup()
    dm = ExportGnsDataModule(str(hopper_export), history=2)
    dm.setup()
    assert dm.conditioning == ours.conditioning == ["alpha", "mu_s", "mu_r"]
    a, b = ours.norm, dm.norm
    assert a is not None and b is not None and (a.dt, a.length, a.horizon_steps) == (b.dt, b.length, b.horizon_steps)
    assert (a.scalar_lo, a.scalar_hi) == (b.scalar_lo, b.scalar_hi)
    np.testing.assert_allclose(b.velocity_std, a.velocity_std, rtol=1e-4)
    np.testing.assert_allclose(b.acceleration_mean, a.acceleration_mean, rtol=1e-3, atol=1e-3)
    for part in ("train", "val", "test"):
        assert dm.datasets[part].items == ours.datasets[part].items
    i = len(ours.datasets["train"]) - 3  # late in a run: many particles have left
    x, y = ours.datasets["train"][i], dm.datasets["train"][i]
    assert x.num_nodes == y.num_nodes < 500 and y.wall_distance.shape == (y.num_nodes, 0)
    np.testing.assert_array_equal(x.mask.numpy(), y.mask.numpy())
    np.testing.assert_allclose(y.velocities.numpy(), x.velocities.numpy(), atol=1e-3)
    np.testing.assert_array_equal(x.scalars.numpy(), y.scalars.numpy())
    meta = dm.checkpoint_metadata()
    assert meta["kind"] == "gns" and meta["scene_kind"] == "hopper" and meta["n_extra_walls"] == 0
    assert meta["export"]["format"] == "gns" and meta["export"]["exits"] == "hold"


@pytest.mark.solver
def test_bad_values_are_one_line(hopper_export: Path, tmp_path: Path):
    with pytest.raises(ConfigError, match="data.conditioning"):
        ExportGnsDataModule(str(hopper_export), conditioning=["inlet_velocity"]).setup()
    with pytest.raises(ConfigError, match="data.datamodule.history=99"):
        ExportGnsDataModule(str(hopper_export), history=99)
    with pytest.raises(DataError, match="no export at"):
        ExportGnsDataModule(str(tmp_path / "none")).setup()


@pytest.mark.solver
def test_the_gns_trains_from_the_export(hopper_export: Path, tmp_path: Path):
    run = tmp_path / "run"
    proc = run_module("neuraldem", "train", "experiment=gns_export_tiny", f"data.export_dir={hopper_export}",
                      "trainer.max_steps=3", "trainer.val_check_interval=3", "trainer.log_every_n_steps=1",
                      f"hydra.run.dir={run}", env={"NEURALDEM_DATA": str(tmp_path)})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    ckpt = run / "checkpoints" / "last.ckpt"
    assert ckpt.is_file()
    lines = (run / "csv" / "metrics.csv").read_text().splitlines()
    header = lines[0].split(",")
    losses = [float(r.split(",")[header.index("train/loss")]) for r in lines[1:] if r.split(",")[header.index(
        "train/loss")]]
    assert len(losses) == 3 and np.isfinite(losses).all()
    assert read_checkpoint(ckpt).hyper_parameters["metadata"]["export"]["dir"] == str(hopper_export.resolve())
    with pytest.raises(DataError, match="trained from the export"):
        load_gns_checkpoint(ckpt)


def test_a_missing_export_dir_is_one_line(tmp_path: Path):
    proc = run_module("neuraldem", "train", "experiment=gns_export_tiny", f"hydra.run.dir={tmp_path}/run",
                      env={"NEURALDEM_DATA": str(tmp_path)})
    assert proc.returncode == 2 and "data.export_dir is required" in proc.stderr, proc.stderr
