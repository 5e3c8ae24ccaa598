"""Shared test setup: quiet, CPU-friendly threading; a private data dir; the Hydra config, shrunk for CPU."""

from __future__ import annotations

import os

# Spinning OpenMP threads make small ops several times slower on a shared 2-core machine.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("WANDB_MODE", "offline")
os.environ.setdefault("WANDB_SILENT", "true")

import shutil
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

torch.set_num_threads(int(os.environ.get("NEURALDEM_TEST_THREADS", "1")))


@pytest.fixture(scope="session")
def data_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A data dir for the whole test session, so tests never touch the user's $NEURALDEM_DATA.

    Set NEURALDEM_TEST_DATA to reuse solver datasets between test sessions (they are resumable)."""
    keep = os.environ.get("NEURALDEM_TEST_DATA")
    root = Path(keep) if keep else tmp_path_factory.mktemp("neuraldem-data")
    root.mkdir(parents=True, exist_ok=True)
    return root


@pytest.fixture(autouse=True)
def _private_data_dir(data_root: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NEURALDEM_DATA", str(data_root))


@pytest.fixture
def compose_train_cfg(tmp_path: Path):
    """Compose `conf/train.yaml` with overrides, shrunk for a CPU test run (no logger, few steps)."""
    from tests.helpers import compose_cfg

    def _compose(*overrides: str, config_name: str = "train"):
        return compose_cfg(config_name, list(overrides), output_dir=tmp_path)

    return _compose


@pytest.fixture(scope="session")
def hopper_tiny_dataset(data_root: Path) -> Path:
    """A real LIGGGHTS dataset at test size (hopper_tiny, 8 simulations with characterization), made once
    per session with the datagen pipeline (resumable: reused when NEURALDEM_TEST_DATA is set)."""
    from omegaconf import open_dict

    from neuraldem.datagen.driver import DatagenOptions, generate
    from neuraldem.scenes.hopper.dataset.datagen import HopperPipeline
    from tests.helpers import compose_cfg

    os.environ["NEURALDEM_DATA"] = str(data_root)
    cfg = compose_cfg("datagen", ["data=hopper_tiny"], output_dir=data_root / "runs")
    with open_dict(cfg):
        cfg.data.dataset_dir = str(data_root / "datasets" / "hopper_tiny")
    pipe = HopperPipeline(cfg.data)
    m = generate(pipe, DatagenOptions(n_sims=8, workers=1, progress=False))
    assert len(m.usable()) >= 6, [(r.sim_id, r.status, r.reason) for r in m.simulations]
    return pipe.dataset_dir


def train_briefly(module, dm, path: Path) -> Path:
    """Train `module` for 3 steps (no validation) and save it to `path`: a checkpoint for plumbing tests."""
    import lightning as L

    trainer = L.Trainer(max_steps=3, accelerator="cpu", logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, limit_val_batches=0)
    trainer.fit(module, datamodule=dm)
    trainer.save_checkpoint(path)
    return path


@pytest.fixture(scope="session")
def tiny_checkpoint(hopper_tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A HopperModule trained for 3 steps on the tiny dataset (for evaluation plumbing, not accuracy)."""
    from neuraldem.models.registry import net_config
    from neuraldem.scenes.hopper.surrogate.datamodule import HopperDataModule
    from neuraldem.scenes.hopper.surrogate.module import HopperModule

    torch.manual_seed(0)  # as the bed fixtures: the same 3 steps whichever tests ran before
    dm = HopperDataModule(str(hopper_tiny_dataset), "hopper_tiny", ["t", "alpha", "mu_s", "mu_r"], n_queries=32)
    return train_briefly(HopperModule(net_config("hopper_tiny"), datamodule=dm), dm,
                         tmp_path_factory.mktemp("ckpt") / "tiny.ckpt")


@pytest.fixture(scope="session")
def fb_tiny_dataset(data_root: Path) -> Path:
    """A real fb_tiny dataset (2 velocities: 2 + 1 packings, raw cases kept under runs/)."""
    from tests.helpers import generate_fb_tiny

    return generate_fb_tiny(data_root)


@pytest.fixture(scope="session")
def fb_tiny_case(fb_tiny_dataset: Path) -> Path:
    """The raw DPMFoam case of the dataset's first trajectory (time directories, logs, monitors)."""
    return fb_tiny_dataset / "runs" / "sim_0000"


@pytest.fixture(scope="session")
def fb_tiny_checkpoint(fb_tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A BedModule trained for 3 steps on fb_tiny (for rollout/evaluation plumbing, not accuracy)."""
    from neuraldem.models.registry import net_config
    from neuraldem.scenes.fluidized_bed.surrogate.datamodule import BedDataModule
    from neuraldem.scenes.fluidized_bed.surrogate.module import BedModule

    torch.manual_seed(0)
    dm = BedDataModule(str(fb_tiny_dataset), "fb_tiny", batch_size=2)
    return train_briefly(BedModule(net_config("fb_tiny"), datamodule=dm), dm,
                         tmp_path_factory.mktemp("ckpt") / "fb_tiny.ckpt")


@pytest.fixture(scope="session")
def fb_tiny_flux_checkpoint(fb_tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Like fb_tiny_checkpoint, with the recipe's stability options: solids-flux channels, mixing advected by the
    predicted flux, volume projection, unroll 1-2 steps, auto noise, and a stochastic net (2 CRPS members)."""
    from neuraldem.models.registry import net_config
    from neuraldem.scenes.fluidized_bed.surrogate.datamodule import BedDataModule
    from neuraldem.scenes.fluidized_bed.surrogate.module import BedModule

    torch.manual_seed(0)
    dm = BedDataModule(str(fb_tiny_dataset), "fb_tiny", batch_size=2, push_forward_steps=2,
                                solids_flux=True)
    stability = {"unroll": [0.5, 0.5], "input_noise": "auto", "conserve_volume": True, "mixing": "advect",
                 "ensemble": 2}
    module = BedModule(net_config("fb_tiny", noise_dim=4), datamodule=dm, stability=stability)
    return train_briefly(module, dm, tmp_path_factory.mktemp("ckpt") / "fb_tiny_flux.ckpt")


@pytest.fixture(scope="session")
def hopper_refill_tiny_dataset(data_root: Path) -> Path:
    """A real LIGGGHTS refilling-hopper dataset at test size (hopper_refill_tiny: 4 simulations of 2 s), made
    once per session with the datagen pipeline (resumable: reused when NEURALDEM_TEST_DATA is set)."""
    from omegaconf import open_dict

    from neuraldem.datagen.driver import DatagenOptions, generate
    from neuraldem.scenes.hopper_refill.datagen import RefillPipeline
    from tests.helpers import compose_cfg

    os.environ["NEURALDEM_DATA"] = str(data_root)
    cfg = compose_cfg("datagen", ["data=hopper_refill_tiny"], output_dir=data_root / "runs")
    with open_dict(cfg):
        cfg.data.dataset_dir = str(data_root / "datasets" / "hopper_refill_tiny")
    pipe = RefillPipeline(cfg.data)
    m = generate(pipe, DatagenOptions(n_sims=4, workers=1, progress=False))
    assert all(r.status == "ok" for r in m.simulations[:4]), [(r.sim_id, r.status, r.reason) for r in m.simulations]
    return pipe.dataset_dir


@pytest.fixture(scope="session")
def refill_tiny_checkpoint(hopper_refill_tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A refill HopperModule trained for 3 steps on hopper_refill_tiny (window 0.25 s; plumbing, not accuracy)."""
    from neuraldem.models.registry import net_config
    from neuraldem.scenes.hopper.surrogate.module import HopperModule
    from neuraldem.scenes.hopper_refill.datamodule import RefillDataModule

    dm = RefillDataModule(str(hopper_refill_tiny_dataset), "hopper_refill_tiny", ["dt_ref", "alpha", "mu_s", "mu_r"],
                          window=0.25, n_queries=32, batch_size=2)
    return train_briefly(HopperModule(net_config("hopper_tiny"), datamodule=dm), dm,
                         tmp_path_factory.mktemp("ckpt") / "refill.ckpt")


# benchmark fixtures: evaluated run folders made from the tiny checkpoint on the real tiny dataset (used by the
# shared bench tests and the hopper's bench adapters)
def make_run(root: Path, name: str, ckpt: Path, dataset: Path, n_queries: int = 32) -> Path:
    """A run folder as `neuraldem.train evaluate=true` leaves it: checkpoints/, evaluation/, .hydra/."""
    from neuraldem.scenes.hopper.analysis.evaluation import evaluate_checkpoint

    run = root / name
    (run / "checkpoints").mkdir(parents=True)
    shutil.copy2(ckpt, run / "checkpoints" / "last.ckpt")
    (run / ".hydra").mkdir()
    OmegaConf.save({"data": {"datamodule": {"n_queries": n_queries}}}, run / ".hydra" / "config.yaml")
    evaluate_checkpoint(run / "checkpoints" / "last.ckpt", run / "evaluation", root, dataset_dir=dataset,
                        vtk=False, progress=False)
    return run


@pytest.fixture(scope="session")
def evaluated_runs(tiny_checkpoint: Path, hopper_tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with one evaluated run and a copy of it under a sweep sub-folder (`multirun/0`)."""
    root = tmp_path_factory.mktemp("runs")
    run = make_run(root, "tiny", tiny_checkpoint, hopper_tiny_dataset)
    shutil.copytree(run, root / "multirun" / "0")
    return root


@pytest.fixture(scope="session")
def tiny_pretrained(tiny_checkpoint: Path, hopper_tiny_dataset: Path,
                    tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A shipped-model folder built from the tiny checkpoint (`hopper_tiny_test`, plumbing only): what
    `predict --verify` and `scan --verify` run against with LIGGGHTS at the tiny scene."""
    from neuraldem.scenes.hopper.release import build_hopper

    out = tmp_path_factory.mktemp("pretrained")
    build_hopper(tiny_checkpoint, "hopper_tiny_test", out, hopper_tiny_dataset)
    return out


@pytest.fixture(scope="session")
def fb_tiny_pretrained(fb_tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A shipped-model folder (`fb_tiny_test`) built from a 3-step model of fb_tiny. Plumbing only: fb_tiny has
    3 real DPMFoam runs and the scalar GP needs 3 to fit, so this copy of the dataset trains on all three and
    "holds out" one of them again; its test errors mean nothing, they only exercise the path."""
    import json

    from neuraldem.models.registry import net_config
    from neuraldem.scenes.fluidized_bed.release import build_fluidized_bed
    from neuraldem.scenes.fluidized_bed.surrogate.datamodule import BedDataModule
    from neuraldem.scenes.fluidized_bed.surrogate.module import BedModule
    from tests.helpers import copy_dataset

    data = copy_dataset(fb_tiny_dataset, tmp_path_factory.mktemp("fb_whatif") / "fb_tiny")
    m = json.loads((data / "manifest.json").read_text())
    ids = [s["sim_id"] for s in m["simulations"] if s["status"] == "ok"]
    m["splits"]["velocity"] = {"train": ids, "val": [], "test": ids[-1:]}
    (data / "manifest.json").write_text(json.dumps(m))
    torch.manual_seed(0)
    dm = BedDataModule(str(data), "fb_tiny", batch_size=2, push_forward_steps=2, solids_flux=True)
    stability = {"unroll": [0.5, 0.5], "conserve_volume": True, "mixing": "advect"}
    ckpt = train_briefly(BedModule(net_config("fb_tiny"), datamodule=dm, stability=stability), dm,
                         tmp_path_factory.mktemp("ckpt") / "fb_whatif.ckpt")
    out = tmp_path_factory.mktemp("pretrained_fb")
    build_fluidized_bed(ckpt, "fb_tiny_test", out, data, lacey_time=0.1, progress=False)
    return out


# the tiny shipped model (built from the tiny real dataset above), for the what-if and explorer tests
TINY = "hopper_tiny_test"


@pytest.fixture(scope="module")
def tiny_engine(tiny_pretrained: Path):
    from neuraldem import pretrained
    from neuraldem.scenes.hopper.explorer.engine import HopperEngine

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NEURALDEM_PRETRAINED_DIR", str(tiny_pretrained))
        return HopperEngine(pretrained.load(TINY, "hopper"))


@pytest.fixture
def use_tiny_model(tiny_pretrained: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """`neuraldem predict` and `serve` in this process see the tiny model."""
    monkeypatch.setenv("NEURALDEM_PRETRAINED_DIR", str(tiny_pretrained))
    return tiny_pretrained
