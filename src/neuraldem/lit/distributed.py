"""Data-parallel training (Lightning DDP) that trains as one process would, and its launcher for Hydra jobs.

Batches: `data.datamodule.batch_size` is the global batch B. With W processes (trainer.devices x num_nodes)
each trains on B / W samples per step (`rank_batch_size`; B must be divisible by W). The training order is the
one-process order dealt out by `data.resumable.ResumableSampler`: process r takes positions r, r + W, ... so
that row j of its batch is row r + W j of the one-process batch.

Randomness inside a training step (supernode picks, input and latent noise, unroll lengths, re-sampled particle
positions) comes from `TrainingDraws`: each row of the global batch draws from its own generator, seeded by
(seed, batch number, what is drawn, global row), so every process draws, for its rows, what the one-process
run drew for them, and a resumed run draws what the uninterrupted one drew. Losses that are a mean over a
varying number of points (masked means) divide by the mean count over the processes
(`SurrogateModule.shared_count`): DDP's average of the processes' gradients is then the gradient of the
global batch's mean, as in one process.

Launching: `JobDDPStrategy` is Lightning's DDP whose extra processes on a node run this Hydra job's own
composed config (saved to a file) in its run folder, logging errors only: in a sweep (`-m`)
Lightning's default would re-run the whole command line, sweep included. Under Slurm (srun) and torchrun the
processes are started outside, and no launcher runs.
"""

from __future__ import annotations

import atexit
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lightning.pytorch.strategies import DDPStrategy
from lightning.pytorch.strategies.launchers.subprocess_script import _SubprocessScriptLauncher
from lightning.pytorch.utilities.rank_zero import rank_zero_only
from omegaconf import DictConfig, OmegaConf

from neuraldem.data.part_loaders import rank_batch_size
from neuraldem.machine import cpu_count

log = logging.getLogger(__name__)

TRAIN_MODULE = "neuraldem.train"


def _stream_id(stream: str) -> int:
    return zlib.crc32(stream.encode())


def keyed_generator(key: Sequence[int], device: torch.device | str = "cpu") -> torch.Generator:
    """A torch generator seeded by a tuple of non-negative integers (same key, same draws)."""
    seed = int(np.random.SeedSequence([int(k) for k in key]).generate_state(1, dtype=np.uint64)[0]) >> 1
    device = torch.device(device)
    if device.type not in ("cpu", "cuda"):
        device = torch.device("cpu")
    return torch.Generator(device=device).manual_seed(seed)


class TrainingDraws:
    """The random draws of one training batch, the same whatever the number of processes: see the module
    docstring. `rank`/`world` place this process's rows in the global batch; `members` > 1 stacks the batch
    that many times (member-major, as an ensemble does), each copy with its own draws."""

    def __init__(self, seed: int, batch: int, rank: int = 0, world: int = 1, device: torch.device | str = "cpu"):
        self.seed, self.batch, self.rank, self.world = int(seed), int(batch), int(rank), int(world)
        self.device = torch.device(device)

    def global_row(self, j: int) -> int:
        """The global-batch row of this process's row j."""
        return self.rank + self.world * j

    def batch_generator(self, stream: str) -> torch.Generator:
        """One CPU generator for a draw made once per batch (the same on every process)."""
        return keyed_generator((self.seed, self.batch, _stream_id(stream)))

    def generators(self, stream: str, rows: int, members: int = 1) -> list[torch.Generator]:
        """One generator per row of this process's (members x rows) stacked batch, on its device."""
        sid = _stream_id(stream)
        return [keyed_generator((self.seed, self.batch, sid, self.global_row(j) + 1, m), self.device)
                for m in range(members) for j in range(rows)]

    def rows(self, stream: str, rows: int, shape: Sequence[int], kind: str = "normal", members: int = 1,
             dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """(members * rows, *shape) draws, standard normal or uniform on [0, 1), row by row."""
        draw = {"normal": torch.randn, "uniform": torch.rand}[kind]
        out = [draw(tuple(shape), generator=g, device=g.device, dtype=dtype)
               for g in self.generators(stream, rows, members)]
        return torch.stack(out).to(self.device)


# ---- launching
def _quoted(value: str) -> str:
    """A Hydra override value in single quotes (paths with spaces, '=' or ',')."""
    return "'" + value.replace("\\", "\\\\").replace("'", "\\'") + "'"


def child_command(job_file: Path, output_dir: str) -> list[str]:
    """The command of another process of the same job: the composed config as saved, the same run folder,
    no second .hydra folder, no log file (errors still reach stderr)."""
    return [sys.executable, "-m", TRAIN_MODULE, f"--config-dir={job_file.parent}", f"--config-name={job_file.stem}",
            f"hydra.run.dir={_quoted(str(output_dir))}", "hydra.output_subdir=null", "hydra/job_logging=none",
            "hydra/hydra_logging=none"]


class _JobLauncher(_SubprocessScriptLauncher):
    """Lightning's launcher of the node's other processes, each running the job's saved config."""

    def __init__(self, strategy: JobDDPStrategy):
        super().__init__(strategy.cluster_environment, strategy.num_processes, strategy.num_nodes)
        self.strategy = strategy

    def _call_children_scripts(self) -> None:
        cfg = self.strategy.job_config
        if cfg is None:  # not started by neuraldem.train: Lightning's own command line
            super()._call_children_scripts()
            return
        self._check_can_spawn_children()
        env = self.cluster_environment
        os.environ.update({"MASTER_ADDR": env.main_address, "MASTER_PORT": str(env.main_port),
                           "NODE_RANK": str(env.node_rank()), "LOCAL_RANK": str(env.local_rank()),
                           "WORLD_SIZE": str(self.num_processes * self.num_nodes)})
        folder = Path(tempfile.mkdtemp(prefix="neuraldem-ddp-"))
        atexit.register(shutil.rmtree, folder, ignore_errors=True)
        job_file = folder / "job.yaml"
        OmegaConf.save(cfg, job_file, resolve=True)
        command = child_command(job_file, str(cfg.paths.output_dir))
        self.procs = [subprocess.Popen(command, env={**os.environ, "LOCAL_RANK": str(local_rank)}, cwd=os.getcwd())
                      for local_rank in range(1, self.num_processes)]


class JobDDPStrategy(DDPStrategy):
    """DDP (`trainer.strategy`) whose other processes on this node run `job_config`, set by `neuraldem.train`
    before fitting; see the module docstring. Every other argument is Lightning's DDPStrategy's."""

    job_config: DictConfig | None = None

    def _configure_launcher(self) -> None:
        super()._configure_launcher()
        if isinstance(self._launcher, _SubprocessScriptLauncher):
            self._launcher = _JobLauncher(self)


# strategy names a trainer config may give that mean this module's strategy (config.build.build_trainer)
STRATEGIES = {"ddp": JobDDPStrategy}


def prepare(trainer: Any, cfg: DictConfig) -> None:
    """Before fitting: the global batch splits evenly, a warning for more processes than cores, and the job's
    config for the processes the strategy starts."""
    world = int(trainer.world_size)
    batch = OmegaConf.select(cfg, "data.datamodule.batch_size")
    if world > 1 and isinstance(batch, int):
        rank_batch_size(batch, world)
    processes, cores = int(trainer.num_devices), cpu_count()
    if processes > cores and rank_zero_only.rank == 0:
        log.warning("%d training processes on this node (trainer.devices=%s) but only %d CPU cores to run them: "
                    "they will share cores and each step will be slower than with fewer processes (set "
                    "trainer.devices=%d or fewer)", processes, cfg.trainer.get("devices"), cores, cores)
    if isinstance(trainer.strategy, JobDDPStrategy):
        trainer.strategy.job_config = cfg


LAUNCH_ENV = ("MASTER_ADDR", "MASTER_PORT", "NODE_RANK", "LOCAL_RANK", "WORLD_SIZE")


def finish(trainer: Any) -> None:
    """After training (and testing), in the process that started the others: wait for them to end, close the
    process group and forget its address, so that the next job of a sweep run in this process (Hydra's basic
    launcher) starts processes of its own."""
    launcher = getattr(trainer.strategy, "launcher", None)
    if not isinstance(launcher, _JobLauncher) or not launcher.procs:
        return
    for proc in launcher.procs:
        proc.wait()
    launcher.procs = []
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        torch.distributed.destroy_process_group()
    for key in LAUNCH_ENV:
        os.environ.pop(key, None)


def quiet_other_ranks() -> None:
    """On processes other than global rank 0 (children, Slurm tasks) only errors are logged: every process
    trains alike, and rank 0's log (the run folder's <job>.log) says each message once."""
    if rank_zero_only.rank > 0:
        logging.getLogger().setLevel(logging.ERROR)
