"""A stand-in Slurm for tests (test double): `sbatch`, `srun`, `squeue` and `sacct` as far as submitit's
SlurmExecutor and neuraldem's datagen use them, running the array tasks on this machine.

`install(bin_dir, state_dir)` writes the four commands into `bin_dir`. `sbatch FILE` reads `#SBATCH --array=0-M%P`
and the command line of the script submitit wrote, prints `Submitted batch job ID` and starts a runner that runs
the tasks (at most P at a time) with the environment Slurm gives an array task. Task states live in `state_dir`
(one file per task: PENDING, RUNNING, COMPLETED or FAILED), which `squeue` and `sacct` report.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

STATE_ENV = "FAKE_SLURM_STATE"


def install(bin_dir: Path, state_dir: Path, sacct: bool = True) -> dict[str, str]:
    """Write the commands (`sacct=False`: a cluster without job accounting, whose sacct fails); returns the
    environment to run datagen with (PATH first, the state folder)."""
    bin_dir.mkdir(parents=True, exist_ok=True)
    state_dir.mkdir(parents=True, exist_ok=True)
    if not sacct:
        path = bin_dir / "sacct"
        path.write_text("#!/bin/sh\necho 'sacct: error: Slurm accounting storage is disabled' >&2\nexit 1\n")
        path.chmod(0o755)
    for cmd in ("sbatch", "srun", "squeue") + (("sacct",) if sacct else ()):
        path = bin_dir / cmd
        path.write_text(f"#!/bin/sh\nexec {shlex.quote(sys.executable)} {shlex.quote(__file__)} {cmd} \"$@\"\n")
        path.chmod(0o755)
    return {"PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", STATE_ENV: str(state_dir)}


def _states() -> Path:
    return Path(os.environ[STATE_ENV])


def sbatch(args: list[str]) -> None:
    script = Path(args[-1]).read_text()
    array = re.search(r"^#SBATCH --array=0-(\d+)%(\d+)$", script, re.M)
    n, parallel = (int(array.group(1)) + 1, int(array.group(2))) if array else (0, 1)  # 0: not an array
    command = script.split("export SUBMITIT_EXECUTOR=slurm\n", 1)[1].strip().splitlines()[0]
    job_id = str(1000 + len(list(_states().glob("job_*"))))
    (_states() / f"job_{job_id}").write_text(command)
    for task in _task_ids(job_id, n):
        (_states() / task).write_text("PENDING")
    subprocess.Popen([sys.executable, __file__, "run", job_id, str(n), str(parallel)], stdin=subprocess.DEVNULL,
                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    print(f"Submitted batch job {job_id}")


def _task_ids(job_id: str, n: int) -> list[str]:
    return [f"{job_id}_{a}" for a in range(n)] if n else [job_id]


def run(job_id: str, n: str, parallel: str) -> None:
    command = (_states() / f"job_{job_id}").read_text()
    todo, running = _task_ids(job_id, int(n)), {}
    while todo or running:
        while todo and len(running) < int(parallel):
            task = todo.pop(0)
            env = dict(os.environ, SUBMITIT_EXECUTOR="slurm", SLURM_JOB_ID=job_id, SLURM_NTASKS="1",
                       SLURM_JOB_NUM_NODES="1", SLURM_NODEID="0", SLURM_PROCID="0", SLURM_LOCALID="0",
                       SLURM_JOB_NODELIST="localhost")
            if "_" in task:
                env.update(SLURM_JOB_ID=str(int(job_id) + 1 + int(task.split("_")[1])), SLURM_ARRAY_JOB_ID=job_id,
                           SLURM_ARRAY_TASK_ID=task.split("_")[1])
            (_states() / task).write_text("RUNNING")
            running[task] = subprocess.Popen(["sh", "-c", command], env=env)
        for task, proc in list(running.items()):
            if proc.poll() is not None:
                (_states() / task).write_text("COMPLETED" if proc.returncode == 0 else "FAILED")
                del running[task]
        time.sleep(0.1)


def srun(args: list[str]) -> None:
    """`srun [--unbuffered] --output F --error F CMD...`: CMD with its output in those files (%A %a %t filled)."""
    files, k = {}, 0
    while args[k].startswith("--"):
        if args[k] in ("--output", "--error"):
            files[args[k]] = args[k + 1]
            k += 2
        else:
            k += 1
    fill = {"%A": os.environ.get("SLURM_ARRAY_JOB_ID", ""), "%a": os.environ.get("SLURM_ARRAY_TASK_ID", ""),
            "%j": os.environ["SLURM_JOB_ID"], "%t": "0"}
    for key, path in files.items():
        for pattern, value in fill.items():
            path = path.replace(pattern, value)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND)
        os.dup2(fd, 1 if key == "--output" else 2)
    os.execvp(args[k], args[k:])


def _tasks(job_ids: list[str]) -> list[tuple[str, str]]:
    out = []
    for job_id in job_ids:
        main = job_id.split("_")[0]
        out += [(p.name, p.read_text()) for p in sorted(_states().glob(f"{main}*")) if p.name.split("_")[0] == main]
    return out


def squeue(args: list[str]) -> None:
    """`--array`: one line per pending or running task (`ID_INDEX`); else the job id while any task is."""
    job_ids = args[args.index("--jobs") + 1].split(",")
    queued = [name for name, state in _tasks(job_ids) if state in ("PENDING", "RUNNING")]
    if "--array" in args:
        print("\n".join(queued))
    elif queued:
        print(job_ids[0])


def sacct(args: list[str]) -> None:
    job_ids = [args[k + 1] for k, a in enumerate(args) if a == "-j"]
    print("JobID|State|NodeList")
    for name, state in _tasks(job_ids):
        print(f"{name}|{state}|localhost")


if __name__ == "__main__":
    cmd, rest = sys.argv[1], sys.argv[2:]
    if cmd == "run":
        run(*rest)
    else:
        {"sbatch": sbatch, "srun": srun, "squeue": squeue, "sacct": sacct}[cmd](rest)
