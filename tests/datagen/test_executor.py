"""`neuraldem datagen executor=...`: the tiny hopper (real LIGGGHTS) run as separate submitit tasks equals a local
run, a killed array resumes keeping finished work, the Slurm dry run writes the sbatch script without sbatch, and
a missing submitit or sbatch, bad executor values and array jobs of an earlier datagen end in one line."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

import pytest

from neuraldem.data.manifest import Manifest
from neuraldem.scenes.hopper.dataset.store import HopperFile
from tests.helpers import REPO, run_module

pytestmark = pytest.mark.solver
FAST = ["data=hopper_tiny", "data.characterization.enabled=false", "progress=false"]
SUBMITIT = ["executor=submitit_local", "executor.poll_s=0.2"]
DATASET = Path("datasets/hopper_tiny")


def datagen(root: Path, *args: str, env: dict[str, str] | None = None):
    """`neuraldem datagen` of 3 tiny hopper runs (or args' n_sims=: each key is given once)."""
    n_sims = [] if any(a.startswith("n_sims=") for a in args) else ["n_sims=3"]
    return run_module("neuraldem", "datagen", *FAST, *n_sims, *args, env={"NEURALDEM_DATA": str(root), **(env or {})})


def manifest(root: Path) -> Manifest:
    return Manifest.load(root / DATASET)


def stamp(root: Path, rec) -> tuple[str, int]:
    return rec.sha256, (root / DATASET / rec.file).stat().st_mtime_ns


def no_leftovers(root: Path) -> None:
    assert not list((root / DATASET).glob("records/*.json")), "task records left unmerged"
    assert not (root / DATASET / "array_jobs.json").exists()
    assert not list((root / DATASET).rglob("*.partial"))


def test_submitit_local_runs_a_tiny_datagen_like_a_local_run(tmp_path: Path):
    local = datagen(tmp_path / "local")
    assert local.returncode == 0, local.stderr
    root = tmp_path / "sub"
    sub = datagen(root, *SUBMITIT, "workers=2")
    assert sub.returncode == 0, sub.stderr
    assert "0 finished, 3 to run as submitit local tasks (2 at a time" in sub.stdout + sub.stderr
    a, b = manifest(tmp_path / "local"), manifest(root)
    assert [(r.sim_id, r.status, r.params, r.metrics) for r in a.simulations] == \
        [(r.sim_id, r.status, r.params, r.metrics) for r in b.simulations]
    assert b.splits == a.splits
    for r in b.simulations:
        HopperFile(root / DATASET / r.file).close()
    no_leftovers(root)
    logs = list((root / "runs/datagen").glob("*/submitit/*_0_log.err"))  # one process per simulation
    assert len(logs) == 3 and all("Job completed successfully" in p.read_text() for p in logs)

    # records a later datagen finds: one whose file was damaged after it was written runs again; one from another
    # parameter table (e.g. a dataset folder reused) is ignored; the others stay as they are
    kept = {r.sim_id: stamp(root, r) for r in b.simulations[:2]}
    damaged = b.record("sim_0002")
    path = root / DATASET / damaged.file
    path.write_bytes(path.read_bytes()[:100])
    records = root / DATASET / "records"
    (records / "sim_0002.json").write_text(json.dumps(asdict(damaged)))
    (records / "sim_0001.json").write_text(json.dumps({**asdict(b.record("sim_0001")), "params": {"alpha": 1.0},
                                                       "status": "failed"}))
    again = datagen(root, *SUBMITIT)
    assert again.returncode == 0, again.stderr
    out = again.stdout + again.stderr
    assert "2 finished, 1 to run" in out and "another parameter table" in out
    m = manifest(root)
    assert [r.status for r in m.simulations] == ["ok"] * 3
    assert {r.sim_id: stamp(root, r) for r in m.simulations[:2]} == kept
    HopperFile(path).close()
    no_leftovers(root)


def test_killed_array_resumes_keeping_finished_simulations(tmp_path: Path):
    env = dict(os.environ, NEURALDEM_DATA=str(tmp_path))
    cmd = [sys.executable, "-m", "neuraldem", "datagen", *FAST, "n_sims=3", *SUBMITIT, "executor.array_parallelism=1"]
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    path = tmp_path / DATASET / "manifest.json"
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if path.exists() and any(r["status"] == "ok" for r in json.loads(path.read_text())["simulations"]):
            break
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)  # the datagen, its submitit tasks and their LIGGGHTS
    proc.wait()
    first = [r for r in manifest(tmp_path).simulations if r.status == "ok"]
    assert 1 <= len(first) < 3
    done = {r.sim_id: stamp(tmp_path, r) for r in first}
    left = len(list((tmp_path / DATASET).glob("records/*.json")))  # finished by a task, not yet merged

    again = run_module("neuraldem", "datagen", *cmd[4:], env={"NEURALDEM_DATA": str(tmp_path)})
    assert again.returncode == 0, again.stderr
    n = len(first) + left
    assert f"{n} finished, {3 - n} to run" in again.stdout + again.stderr
    m = manifest(tmp_path)
    assert [r.status for r in m.simulations] == ["ok"] * 3
    for r in m.simulations:
        if r.sim_id in done:  # untouched: same checksum, same file
            assert stamp(tmp_path, r) == done[r.sim_id]
        HopperFile(tmp_path / DATASET / r.file).close()
    no_leftovers(tmp_path)


SLURM_COMMANDS = {"sbatch", "srun", "squeue", "sacct", "scancel", "sinfo", "salloc"}


def without_sbatch(tmp_path: Path) -> str:
    """This PATH without the Slurm commands (also on a machine with Slurm installed, as CI's local one): one folder
    of links to everything else on it (LIGGGHTS and the Open MPI tools its start runs among them)."""
    bin_dir = tmp_path / "no-slurm-bin"
    bin_dir.mkdir(exist_ok=True)
    for folder in os.environ["PATH"].split(os.pathsep):
        for tool in Path(folder).glob("*") if Path(folder).is_dir() else ():
            link = bin_dir / tool.name
            if tool.name not in SLURM_COMMANDS and not link.exists() and not link.is_symlink():
                link.symlink_to(tool)
    path = os.pathsep.join([str(bin_dir), os.path.dirname(sys.executable)])
    assert not shutil.which("sbatch", path=path) and not shutil.which("srun", path=path)
    return path


def test_dry_run_writes_the_sbatch_script_and_submits_nothing(tmp_path: Path):
    proc = datagen(tmp_path, "executor=slurm", "executor.partition=short", "executor.array_parallelism=2",
                   "executor.dry_run=true", "executor.time_min=30", env={"PATH": without_sbatch(tmp_path)})
    assert proc.returncode == 0, proc.stderr
    assert "3 of 3 simulations of hopper_tiny would run as Slurm array 0-2%2; nothing submitted" in proc.stdout
    script = Path(re.search(r"sbatch script: (\S+)", proc.stdout).group(1))
    text = script.read_text()
    for line in ("#SBATCH --partition=short", "#SBATCH --array=0-2%2", "#SBATCH --time=30",
                 "#SBATCH --job-name=neuraldem-datagen-hopper_tiny", "#SBATCH --cpus-per-task=1"):
        assert line in text.splitlines(), line
    assert re.search(r"^srun .* -m submitit\.core\._submit \S+/submitit$", text, re.M), text
    tasks = json.loads(Path(re.search(r"task list: (\S+)", proc.stdout).group(1)).read_text())["tasks"]
    assert [t["sim_id"] for t in tasks] == ["sim_0000", "sim_0001", "sim_0002"]
    assert not (tmp_path / DATASET).exists()  # nothing written into the dataset, nothing run


def test_slurm_without_submitit_or_sbatch_and_bad_values_end_in_one_line(tmp_path: Path):
    # "submitit is not installed": a module named submitit first on the path that fails to import as a missing
    # package does (the real one stays installed for the other tests)
    shadow = tmp_path / "shadow"
    shadow.mkdir()
    (shadow / "submitit.py").write_text("raise ModuleNotFoundError(\"No module named 'submitit'\", name='submitit')\n")
    pythonpath = os.pathsep.join([str(shadow), *filter(None, [os.environ.get("PYTHONPATH")])])
    cases = [
        (["executor=slurm", "executor.dry_run=true"], {"PYTHONPATH": pythonpath},
         "executor=slurm needs the submitit package, which is not installed: pip install 'neuraldem[sweep]'"),
        (["executor=submitit_local"], {"PYTHONPATH": pythonpath}, "executor=submitit_local needs the submitit package"),
        (["executor=slurm", "executor.partition=short"], {"PATH": without_sbatch(tmp_path)},
         "sbatch and srun are not on PATH here: run this on a Slurm login node, or use executor=submitit_local"),
        (["executor=slurm", "executor.array_parallelism=0"], {}, "executor.array_parallelism=0 is invalid"),
    ]
    for args, env, message in cases:
        proc = datagen(tmp_path, *args, env=env)
        assert proc.returncode == 2 and message in proc.stderr, (args, proc.stderr)
        assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert not (tmp_path / DATASET).exists()
    unknown = datagen(tmp_path, "executor=pbs")  # refused before Hydra composes, listing the executors there are
    assert unknown.returncode == 2 and "no executor config 'pbs': searched" in unknown.stderr
    assert "submitit_local" in unknown.stderr and "slurm" in unknown.stderr


@pytest.mark.parametrize("values,message", [
    ({"kind": "pbs"}, "executor.kind='pbs' is invalid: must be one of ['local', 'submitit_local', 'slurm']"),
    ({"kind": "slurm", "time_min": 0}, "executor.time_min=0 is invalid"),
    ({"kind": "slurm", "time_min": 1.5}, "executor.time_min=1.5 is invalid: must be an integer"),
    ({"kind": "slurm", "mem_gb": "lots"}, "executor.mem_gb='lots' is invalid"),
    ({"kind": "slurm", "cpus_per_task": -1}, "executor.cpus_per_task=-1 is invalid"),
    ({"kind": "slurm", "partition": "a b"}, "executor.partition='a b' is invalid"),
    ({"kind": "slurm", "dry_run": "yes"}, "executor.dry_run='yes' is invalid: must be true or false"),
    ({"kind": "slurm", "setup": "module load x"}, "executor.setup='module load x' is invalid"),
    ({"kind": "slurm", "additional_parameters": {"array": "0-3"}}, "array is set by executor.* settings"),
    ({"kind": "slurm", "additional_parameters": {"constraint": [1]}}, "executor.additional_parameters.constraint"),
    ({"kind": "submitit_local", "array_parallelism": 0}, "executor.array_parallelism=0 is invalid"),
    ({"kind": "local", "partition": "short"}, "unknown key(s) ['partition'] in executor"),
])
def test_executor_values_are_checked(values: dict, message: str):
    from neuraldem.datagen.executors import ExecutorSettings
    from neuraldem.errors import ConfigError

    with pytest.raises(ConfigError) as err:
        ExecutorSettings.from_config(values)
    assert message in str(err.value)


def test_a_datagen_does_not_start_while_an_earlier_array_job_runs(tmp_path: Path):
    """An array job of an earlier datagen (submitted with wait=false, or its submitter killed) that still runs:
    a new datagen, any executor, merges what it finished and refuses to run the same simulations again."""
    from neuraldem.datagen.records import ledger_entry, save_ledger

    dataset = tmp_path / DATASET
    dataset.mkdir(parents=True)
    # stand-in for a submitit local job's controller process (its command line names submitit, as the real one's)
    job = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)", "submitit"])
    try:
        save_ledger(dataset, [ledger_entry("submitit_local", str(job.pid), ["sim_0000", "sim_0001"], tmp_path)])
        proc = datagen(tmp_path)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert "2 simulation(s) are still being run by array job(s) of an earlier datagen" in proc.stderr
        assert f"kill -INT {job.pid}" in proc.stderr and "run the same command again" in proc.stderr
    finally:
        job.kill()
        job.wait()
    from neuraldem.datagen.records import still_running

    assert still_running(dataset) == ([], []) and not (dataset / "array_jobs.json").exists()  # seen ended: dropped


@pytest.mark.timeout(300)
def test_slurm_array_on_a_stand_in_slurm(tmp_path: Path):
    """executor=slurm end to end on a stand-in Slurm (tests/datagen/fake_slurm.py: sbatch runs the array here).
    wait=false submits and returns; a datagen while the array runs merges what it finished and refuses to start;
    one after it ended merges the rest; wait=true then merges further simulations as they finish, and one whose
    task ends without a result stays pending."""
    from tests.datagen import fake_slurm

    env = fake_slurm.install(tmp_path / "bin", tmp_path / "slurm")
    slurm = ["executor=slurm", "executor.partition=debug", "executor.array_parallelism=2", "executor.poll_s=0.2"]
    sub = datagen(tmp_path, *slurm, "executor.wait=false", env=env)
    assert sub.returncode == 0, sub.stderr
    assert "submitted Slurm job array 1000 (3 simulation(s), at most 2 at a time" in sub.stdout
    scripts = list((tmp_path / "runs/datagen").glob("*/submitit/*_submission.sh"))
    assert len(scripts) == 1 and "#SBATCH --array=0-2%2" in scripts[0].read_text()
    ledger = json.loads((tmp_path / DATASET / "array_jobs.json").read_text())["jobs"]
    assert [(j["executor"], j["job_id"], j["sim_ids"]) for j in ledger] == \
        [("slurm", "1000", ["sim_0000", "sim_0001", "sim_0002"])]

    busy = datagen(tmp_path, env=env)  # any executor: the array's simulations must not run twice
    assert busy.returncode == 2 and "still being run by array job(s) of an earlier datagen: Slurm job 1000" \
        in busy.stderr and "scancel 1000" in busy.stderr, busy.stderr
    deadline = time.time() + 300
    while time.time() < deadline and any(p.read_text() in ("PENDING", "RUNNING")
                                         for p in (tmp_path / "slurm").glob("1000_*")):
        time.sleep(0.2)
    merged = datagen(tmp_path, *slurm, env=env)
    assert merged.returncode == 0, merged.stderr
    assert "3 finished, 0 to run" in merged.stdout + merged.stderr
    assert [r.status for r in manifest(tmp_path).simulations] == ["ok"] * 3
    no_leftovers(tmp_path)

    # wait=true: a further simulation runs and is merged as it finishes; one whose solver is stopped from outside
    # (a stand-in LIGGGHTS killed by SIGTERM for sim_0004, as scancel or a node going down would) stays pending
    fake = tmp_path / "liggghts-killed"
    fake.write_text('#!/bin/sh\ncase "$PWD" in *sim_0004*) kill -TERM $$;; esac\nexec liggghts "$@"\n')
    fake.chmod(0o755)
    more = datagen(tmp_path, *slurm, "n_sims=5", env={**env, "NEURALDEM_LIGGGHTS": str(fake)})
    out = more.stdout + more.stderr
    assert more.returncode == 2 and "3 finished, 2 to run on Slurm, partition debug (2 at a time" in out, out
    assert "1 of 2 simulation(s) ended without a result and stay pending (sim_0004: " \
        "neuraldem.errors.SolverInterrupted: liggghts-killed in" in more.stderr, more.stderr
    assert [r.status for r in manifest(tmp_path).simulations] == ["ok"] * 4 + ["pending"]
    no_leftovers(tmp_path)


def test_a_task_that_dies_is_seen_on_a_cluster_without_sacct(tmp_path: Path):
    """Without job accounting (sacct fails) submitit never reports a task killed before it could leave a result
    as done;
    squeue no longer listing it ends the wait: the simulation stays pending and the datagen says so, instead of
    waiting forever (the subprocess timeout here would fail the test)."""
    from tests.datagen import fake_slurm

    env = fake_slurm.install(tmp_path / "bin", tmp_path / "slurm", sacct=False)
    fake = tmp_path / "liggghts-killed"
    # the task's own process killed hard (as scancel, the OOM killer or a lost node do): it leaves no result
    fake.write_text('#!/bin/sh\ncase "$PWD" in *sim_0001*) kill -KILL $PPID; exit 1;; esac\nexec liggghts "$@"\n')
    fake.chmod(0o755)
    proc = run_module("neuraldem", "datagen", *FAST, "n_sims=2", "executor=slurm", "executor.partition=debug",
                      "executor.poll_s=0.2", env={"NEURALDEM_DATA": str(tmp_path), **env,
                                                  "NEURALDEM_LIGGGHTS": str(fake)}, timeout=240)
    assert proc.returncode == 2 and "1 of 2 simulation(s) ended without a result and stay pending (sim_0001: " \
        in proc.stderr, proc.stderr
    assert [r.status for r in manifest(tmp_path).simulations] == ["ok", "pending"]
    no_leftovers(tmp_path)

