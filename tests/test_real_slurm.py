"""Datagen and training on a real Slurm: a one-node cluster on this machine (`bash scripts/local_slurm.sh start`,
then `SLURM_CONF` set; `.ci/run` does both). Skipped, with the reason, where no such Slurm answers.

The stand-in Slurm of tests/datagen/fake_slurm.py checks the bookkeeping; this checks what only a real one
shows: tasks started by slurmd through srun (the solvers' Open MPI must not take them for MPI processes), a
cluster without job accounting (sacct refuses), scancel, and DDP joined by Lightning's SLURMEnvironment."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.helpers import REPO, run_module

pytestmark = pytest.mark.solver
FAST = ["data=hopper_tiny", "data.characterization.enabled=false", "progress=false"]
SLURM = ["executor=slurm", "executor.partition=debug", "executor.mem_gb=1", "executor.poll_s=0.5"]


@pytest.fixture(scope="session")  # before the session-wide dataset fixtures: a skip costs nothing
def slurm() -> None:
    if not os.environ.get("SLURM_CONF") or shutil.which("sinfo") is None:
        pytest.skip("no local Slurm: run `bash scripts/local_slurm.sh start` and export SLURM_CONF")
    out = subprocess.run(["sinfo", "-h", "-o", "%t"], capture_output=True, text=True, timeout=30)
    if out.returncode != 0 or not any(s.startswith(("idle", "mix", "alloc")) for s in out.stdout.split()):
        pytest.skip(f"the local Slurm does not answer (sinfo: {out.stdout.strip() or out.stderr.strip()})")


def ok_count(root: Path) -> int:
    path = root / "datasets" / "hopper_tiny" / "manifest.json"
    return sum(s["status"] == "ok" for s in json.loads(path.read_text())["simulations"]) if path.exists() else 0


def test_a_datagen_array_is_cancelled_and_resumes(slurm: None, tmp_path: Path):
    """One task at a time; after the first simulation, scancel the array: the datagen ends naming the pending
    ones (this cluster keeps no accounting, so squeue tells that the cancelled tasks ended); the same command
    then runs only those, leaving the finished file as it was."""
    env = dict(os.environ, NEURALDEM_DATA=str(tmp_path))
    proc = subprocess.Popen([sys.executable, "-m", "neuraldem", "datagen", *FAST, "n_sims=3", *SLURM,
                             "executor.array_parallelism=1"], env=env, cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 300
    while ok_count(tmp_path) < 1 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.5)
    jobs = subprocess.run(["squeue", "-h", "-o", "%A", "--name", "neuraldem-datagen-hopper_tiny"],
                          capture_output=True, text=True).stdout.split()
    assert jobs, "the array should still run after its first simulation"
    subprocess.run(["scancel", *set(jobs)], check=True)
    _, err = proc.communicate(timeout=300)
    # sacct is disabled on this cluster: the cancelled tasks are seen ended through squeue, not waited for
    assert proc.returncode == 2 and "ended without a result and stay pending" in err, err
    first = tmp_path / "datasets" / "hopper_tiny" / "sims" / "sim_0000.h5"
    digest = hashlib.sha256(first.read_bytes()).hexdigest()
    again = run_module("neuraldem", "datagen", *FAST, "n_sims=3", *SLURM, "executor.array_parallelism=2",
                       env={"NEURALDEM_DATA": str(tmp_path)}, timeout=300)
    assert again.returncode == 0, again.stderr
    assert "1 finished, 2 to run on Slurm, partition debug" in again.stdout + again.stderr
    assert ok_count(tmp_path) == 3 and hashlib.sha256(first.read_bytes()).hexdigest() == digest


def slurm_state(job_name: str) -> str:
    """What Slurm says about a job and the node, for a failure message."""
    cmds = [["squeue", "-h", "-o", "%i %T %r", "--name", job_name], ["sinfo", "-h", "-o", "%N %t %c %m"]]
    return "; ".join(f"{c[0]}: {subprocess.run(c, capture_output=True, text=True).stdout.strip() or '-'}"
                     for c in cmds)


def test_a_two_process_training_joined_by_slurm(slurm: None, hopper_tiny_dataset: Path, tmp_path: Path):
    """hydra/launcher=slurm_ddp: Slurm starts both processes (srun, one task each) and Lightning's
    SLURMEnvironment joins them; rank 0 writes the checkpoints into the run folder."""
    cpus = subprocess.run(["sinfo", "-h", "-o", "%c"], capture_output=True, text=True).stdout.split()
    # a node of one CPU accepts the two-task job and leaves it pending for ever: say so instead of waiting
    assert cpus and int(cpus[0]) >= 2, (f"the local Slurm node has {cpus} CPUs and this job needs 2: restart it "
                                        "with `bash scripts/local_slurm.sh start` (it counts the machine's cores)")
    cmd = [sys.executable, "-m", "neuraldem", "train", "-m", "hydra/launcher=slurm_ddp",
           "hydra.launcher.partition=debug", "hydra.launcher.cpus_per_task=1", "hydra.launcher.mem_gb=1",
           "hydra.launcher.timeout_min=10",
           "experiment=hopper_quickstart", "trainer=ddp_cpu", "trainer.devices=2",
           "data.datamodule.batch_size=4", "trainer.max_steps=3", "trainer.val_check_interval=3",
           "evaluate=false", "callbacks.progress=null", "logger=none", "seed=0",
           f"hydra.sweep.dir={tmp_path / 'sweep'}", "hydra.launcher.name=neuraldem-ddp-test"]
    env = dict(os.environ, NEURALDEM_DATA=str(hopper_tiny_dataset.parent.parent))
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _, err = proc.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        state = slurm_state("neuraldem-ddp-test")
        subprocess.run(["scancel", "--name", "neuraldem-ddp-test"])
        proc.kill()
        pytest.fail(f"the two-process training did not end in 300 s; Slurm says {state}")
    assert proc.returncode == 0, err
    assert (tmp_path / "sweep" / "0" / "checkpoints" / "last.ckpt").is_file()
    logs = "".join(p.read_text() for p in (tmp_path / "sweep" / ".submitit").rglob("*_log.err"))
    assert "All distributed processes registered. Starting with 2 processes" in logs
    assert "GLOBAL_RANK: 1, MEMBER: 2/2" in logs
