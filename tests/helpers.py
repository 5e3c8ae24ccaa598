"""Helpers shared by tests (importable as `tests.helpers`)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, open_dict

import neuraldem.config  # noqa: F401  (resolvers)
from neuraldem.paths import config_dir

REPO = Path(__file__).resolve().parents[1]

# applied to every composed training config: CPU, tiny runs, no external side effects
CPU_TEST_OVERRIDES = [
    "trainer=cpu",
    "trainer.max_steps=2",
    "trainer.val_check_interval=1",
    "trainer.log_every_n_steps=1",
    "trainer.enable_model_summary=false",
    "logger=none",
]


def compose_cfg(config_name: str, overrides: list[str], output_dir: Path) -> DictConfig:
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        extra = CPU_TEST_OVERRIDES if config_name == "train" else []
        cfg = compose(config_name=config_name, overrides=extra + overrides, return_hydra_config=True)
    HydraConfig.instance().set_config(cfg)
    with open_dict(cfg):
        cfg.paths.output_dir = str(output_dir)
        if "callbacks" in cfg and cfg.callbacks is not None and "progress" in cfg.callbacks:
            cfg.callbacks.progress = None
    return cfg


def run_module(module: str, *args: str, env: dict[str, str] | None = None,
               timeout: float = 600) -> subprocess.CompletedProcess[str]:
    """Run `python -m module args...` as a user would, capturing output."""
    full_env = dict(os.environ, **(env or {}))
    return subprocess.run([sys.executable, "-m", module, *args], cwd=REPO, env=full_env,
                          capture_output=True, text=True, timeout=timeout)


FB_TINY_SIMS = 3  # the low velocity with 2 packings, the high one with 1


def generate_fb_tiny(root: Path, n_sims: int = FB_TINY_SIMS) -> Path:
    from omegaconf import open_dict

    from neuraldem.datagen.driver import DatagenOptions, generate
    from neuraldem.scenes.fluidized_bed.dataset.datagen import BedPipeline

    os.environ["NEURALDEM_DATA"] = str(root)
    cfg = compose_cfg("datagen", ["data=fb_tiny"], output_dir=root / "runs")
    with open_dict(cfg):
        cfg.data.dataset_dir = str(root / "datasets" / "fb_tiny")
    pipe = BedPipeline(cfg.data)
    m = generate(pipe, DatagenOptions(n_sims=n_sims, workers=1, progress=False))
    first = m.simulations[:n_sims]
    assert all(r.status == "ok" for r in first), [(r.sim_id, r.status, r.reason) for r in first]
    return pipe.dataset_dir


def copy_dataset(src: Path, dst: Path) -> Path:
    """A dataset's manifest and HDF5 files (not its raw runs) in a new folder, to damage or edit in a test."""
    import shutil

    dst.mkdir(parents=True, exist_ok=True)
    shutil.copy2(src / "manifest.json", dst / "manifest.json")
    shutil.copytree(src / "sims", dst / "sims")
    return dst


def with_split(src: Path, dst: Path, split: str, part: str, ids_of: str) -> Path:
    """A view of a dataset (its HDF5 files linked, not copied) whose `split` part `part` holds the ids of part
    `ids_of`: e.g. fb_tiny's two-packing training velocity as its test or validation part."""
    import shutil

    from neuraldem.data.manifest import Manifest

    dst.mkdir(parents=True)
    (dst / "sims").symlink_to(src / "sims")
    shutil.copy(src / "manifest.json", dst / "manifest.json")
    m = Manifest.load(dst)
    m.splits[split][part] = list(m.splits[split][ids_of])
    m.save(dst)
    return dst


def run_notebook(name: str) -> dict:
    """Execute the code cells of notebooks/NAME top to bottom; returns their namespace."""
    import json

    nb = json.loads((REPO / "notebooks" / name).read_text())
    namespace: dict = {}
    for cell in nb["cells"]:
        if cell["cell_type"] == "code":
            exec(compile("".join(cell["source"]), name, "exec"), namespace)  # noqa: S102 (our own notebooks)
    return namespace


def train_tiny_gns(dataset: Path, name: str, path: Path) -> Path:
    """A GNS (model gns_tiny, history 2) trained for 3 steps on a tiny dataset, saved at `path` (for rollout
    and benchmark plumbing, not accuracy)."""
    import lightning as L
    import torch
    from omegaconf import OmegaConf

    from neuraldem.gns.datamodule import GnsDataModule
    from neuraldem.gns.module import GnsModule

    torch.manual_seed(0)
    dm = GnsDataModule(str(dataset), name, history=2)
    cfg = OmegaConf.load(config_dir() / "model" / "gns_tiny.yaml")
    module = GnsModule(cfg.net, datamodule=dm, optimizer=cfg.optimizer, scheduler=cfg.scheduler)
    trainer = L.Trainer(max_steps=3, accelerator="cpu", logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, limit_val_batches=0)
    trainer.fit(module, datamodule=dm)
    trainer.save_checkpoint(path)
    return path


def oracle(run, h: int, start: int = 0):
    """A GNS accelerator that returns the stored run's own accelerations (a `ParticleRun`, the model's history
    `h`; particles leaving at the next snapshot are sent down the sink): a rollout with it reproduces the run."""
    import numpy as np

    x, dt = run.positions(), run.dt

    def accelerate(step, inputs):
        k = start + h + step - 1
        alive = np.isfinite(x[k]).all(axis=1)
        a = (x[k + 1] - 2 * x[k] + x[k - 1])[alive] / dt**2
        return np.where(np.isfinite(a), a, [0.0, 0.0, -1e4])

    return accelerate


def rerecord_checksum(dataset: Path, path: Path) -> None:
    """Record a changed run file's checksum in its manifest, as if another tool had written it that way: the
    reader's own checks are then what is tested (the checksum check would refuse it first otherwise)."""
    import json

    from neuraldem.data.schema import sha256

    m = json.loads((dataset / "manifest.json").read_text())
    for r in m["simulations"]:
        if r.get("file") == Path(path).relative_to(dataset).as_posix():
            r["sha256"] = sha256(path)
    (dataset / "manifest.json").write_text(json.dumps(m))


def flip_byte(path: Path) -> None:
    """Flip one byte in the middle of a file (an HDF5 file that may still open: only the checksum knows)."""
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


class KillAtStep:
    """A Lightning callback (test double, added with `+callbacks.kill._target_=tests.helpers.KillAtStep`) that
    SIGKILLs its own process when training reaches `step`, unless NEURALDEM_TEST_NO_KILL is set."""

    def __new__(cls, step: int):  # a Callback subclass made lazily: importing helpers needs no Lightning
        import signal

        import lightning as L

        class _Kill(L.Callback):
            def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:  # noqa: ANN001
                if trainer.global_step == step and not os.environ.get("NEURALDEM_TEST_NO_KILL"):
                    os.kill(os.getpid(), signal.SIGKILL)

        return _Kill()
