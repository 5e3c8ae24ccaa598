"""Results of simulations run in other processes (array tasks), and the array jobs a dataset has out.

An array task (executor=submitit_local or slurm) runs the missing work of one simulation and writes the
resulting record to `<dataset>/records/<sim_id>.json` (atomically: a temporary file renamed into place); it
never writes the manifest. The datagen that holds the dataset's lock merges these files into the manifest,
saves it, and only then deletes them, so a record is always either in a file or in the manifest. Every
datagen (any executor) first merges the files an earlier, killed datagen left behind.

`<dataset>/array_jobs.json` lists the array jobs a datagen submitted and has not yet seen end. A later
datagen does not start while one of them is still running (its tasks would run the same simulations a
second time): it merges what they finished so far and says which job to wait for or cancel.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import socket
import subprocess
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from neuraldem.data.manifest import STATUSES, Manifest, SimRecord
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import DataError

log = logging.getLogger(__name__)

RECORDS_DIR = "records"
LEDGER_NAME = "array_jobs.json"


# ---- one record per finished task
def record_path(dataset_dir: Path, sim_id: str) -> Path:
    return Path(dataset_dir) / RECORDS_DIR / f"{sim_id}.json"


def write_record(dataset_dir: Path, rec: SimRecord) -> Path:
    """Write a task's resulting record (temporary file + rename: a reader never sees half of it)."""
    path = record_path(dataset_dir, rec.sim_id)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, asdict(rec))
    return path


def read_record(dataset_dir: Path, sim_id: str, table: SimRecord, discard: bool = False) -> SimRecord | None:
    """The record file of `sim_id` if there is one that belongs to this row of the parameter table (same index
    and parameters). One that does not (left from another table) or cannot be read is ignored with a warning
    (and deleted when `discard`): the simulation then counts as not run."""
    path = record_path(dataset_dir, sim_id)
    if not path.is_file():
        return None
    try:
        rec = SimRecord(**json.loads(path.read_text()))
        ours = (rec.sim_id, rec.index, rec.params) == (table.sim_id, table.index, table.params)
        problem = None if ours and rec.status in STATUSES else "a task record of another parameter table"
    except (OSError, ValueError, TypeError) as err:
        problem = f"an unreadable task record ({err})"
    if problem is None:
        return rec
    log.warning("%s: %s, ignoring it: %s stays to be run", path, problem, sim_id)
    if discard:
        path.unlink(missing_ok=True)
    return None


def merge_records(m: Manifest, dataset_dir: Path) -> tuple[list[str], list[str]]:
    """Put the task record files of `dataset_dir` into the manifest (in memory). Returns the sim ids merged and
    those of files ignored (another table, unreadable); the caller saves the manifest and then deletes both
    (`drop_records`). Nothing on disk changes here."""
    folder = Path(dataset_dir) / RECORDS_DIR
    if not folder.is_dir():
        return [], []
    rows = {r.sim_id: k for k, r in enumerate(m.simulations)}
    merged, ignored = [], []
    for path in sorted(folder.glob("*.json")):
        sim_id = path.stem
        rec = read_record(dataset_dir, sim_id, m.simulations[rows[sim_id]]) if sim_id in rows else None
        if rec is None:
            if sim_id not in rows:
                log.warning("%s: task record of a simulation this manifest does not list, ignoring it", path)
            ignored.append(sim_id)
            continue
        m.simulations[rows[sim_id]] = rec
        merged.append(sim_id)
    if merged:
        log.info("%s: merged %d result(s) of array tasks: %s", m.name, len(merged), ", ".join(merged))
    return merged, ignored


def drop_records(dataset_dir: Path, sim_ids: list[str]) -> None:
    """Delete task record files once the saved manifest holds them."""
    for sim_id in sim_ids:
        record_path(dataset_dir, sim_id).unlink(missing_ok=True)


# ---- the array jobs a dataset has out
def ledger_path(dataset_dir: Path) -> Path:
    return Path(dataset_dir) / LEDGER_NAME


def load_ledger(dataset_dir: Path) -> list[dict[str, Any]]:
    path = ledger_path(dataset_dir)
    if not path.is_file():
        return []
    try:
        jobs = json.loads(path.read_text())["jobs"]
        if not isinstance(jobs, list):
            raise TypeError("jobs is not a list")
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise DataError(f"{path} is unreadable ({err})",
                        "if no array job of an earlier datagen is still running, delete it and run again") from None
    return jobs


def save_ledger(dataset_dir: Path, jobs: list[dict[str, Any]]) -> None:
    path = ledger_path(dataset_dir)
    if jobs:
        atomic_write_json(path, {"jobs": jobs})
    else:
        path.unlink(missing_ok=True)


def ledger_entry(kind: str, job_id: str, sim_ids: list[str], log_folder: Path) -> dict[str, Any]:
    return {"executor": kind, "job_id": str(job_id), "host": socket.gethostname(), "sim_ids": list(sim_ids),
            "log_folder": str(log_folder), "submitted_utc": datetime.now(UTC).isoformat(timespec="seconds")}


def add_to_ledger(dataset_dir: Path, entries: list[dict[str, Any]]) -> None:
    save_ledger(dataset_dir, load_ledger(dataset_dir) + entries)


def remove_from_ledger(dataset_dir: Path, job_ids: set[str]) -> None:
    save_ledger(dataset_dir, [j for j in load_ledger(dataset_dir) if j.get("job_id") not in job_ids])


def job_running(entry: dict[str, Any]) -> bool | None:
    """Whether an array job of the ledger still runs: True, False, or None when this machine cannot tell (a
    Slurm job seen without `squeue`, a local job of another host)."""
    job_id = str(entry.get("job_id", ""))
    if entry.get("executor") == "slurm":
        if shutil.which("squeue") is None:
            return None
        out = subprocess.run(["squeue", "--noheader", "--jobs", job_id, "--format=%i"], capture_output=True,
                             text=True, timeout=60)
        # an ended job is either listed no more or (older Slurm) refused as an invalid id
        return out.returncode == 0 and bool(out.stdout.strip())
    if entry.get("host") != socket.gethostname():
        return None
    return _submitit_process_alive(int(job_id)) if job_id.isdigit() else False


def slurm_tasks_listed(array_id: str) -> set[str] | None:
    """The tasks of a Slurm array that `squeue` still lists (pending or running, `ARRAY_INDEX` ids); None when
    this machine cannot tell. Without job accounting (`sacct`) submitit never sees a task that died without a
    result end; a task squeue no longer lists has ended."""
    if shutil.which("squeue") is None:
        return None
    try:
        out = subprocess.run(["squeue", "--noheader", "--array", "--jobs", array_id, "--format=%i"],
                             capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if out.returncode != 0:  # an ended array: listed no more or (older Slurm) refused as an invalid id
        return set() if "invalid job id" in out.stderr.lower() else None
    return {line.strip() for line in out.stdout.splitlines() if line.strip()}


def _submitit_process_alive(pid: int) -> bool:
    """A submitit local job is its controller process: alive, not a zombie, and still submitit's (not a new
    process that reuses the number)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    proc = Path(f"/proc/{pid}")
    if not proc.is_dir():
        return True
    try:
        stat = (proc / "stat").read_text()
        cmdline = (proc / "cmdline").read_bytes()
    except OSError:
        return False
    return stat.rpartition(")")[2].split()[0] != "Z" and b"submitit" in cmdline


def still_running(dataset_dir: Path) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """(running, unknown) array jobs of the ledger; jobs seen ended are taken off it."""
    jobs = load_ledger(dataset_dir)
    states = [job_running(j) for j in jobs]
    running = [j for j, s in zip(jobs, states, strict=True) if s is True]
    unknown = [j for j, s in zip(jobs, states, strict=True) if s is None]
    if len(running) + len(unknown) < len(jobs):
        save_ledger(dataset_dir, running + unknown)
    return running, unknown


def earlier_jobs_error(dataset_dir: Path, running: list[dict[str, Any]], unknown: list[dict[str, Any]],
                       merged: int) -> DataError:
    """Why a datagen does not start while array jobs of an earlier one may still run its simulations."""
    jobs = running + unknown
    n = sum(len(j.get("sim_ids", [])) for j in jobs)
    what = ", ".join(_describe(j) for j in jobs)
    done = f" ({merged} finished result(s) merged into the manifest)" if merged else ""
    if running:
        return DataError(f"{dataset_dir}: {n} simulation(s) are still being run by array job(s) of an earlier "
                         f"datagen: {what}{done}",
                         "wait for them to end, or cancel them (" + _cancel_hint(running) + "), and run the same "
                         "command again: finished simulations are kept")
    return DataError(f"{dataset_dir}: {n} simulation(s) were submitted as array job(s) of an earlier datagen "
                     f"that this machine cannot check: {what}{done}",
                     f"run this where they were submitted (a Slurm login node with squeue), or, if they have ended, "
                     f"delete {ledger_path(dataset_dir)} and run again")


def _describe(job: dict[str, Any]) -> str:
    kind = "Slurm job" if job.get("executor") == "slurm" else f"submitit local job (PID on {job.get('host')})"
    return f"{kind} {job.get('job_id')} submitted {job.get('submitted_utc')}, logs in {job.get('log_folder')}"


def _cancel_hint(jobs: list[dict[str, Any]]) -> str:
    slurm = [str(j["job_id"]) for j in jobs if j.get("executor") == "slurm"]
    local = [str(j["job_id"]) for j in jobs if j.get("executor") != "slurm"]
    hints = ([f"scancel {' '.join(slurm)}"] if slurm else []) + ([f"kill -INT {' '.join(local)}"] if local else [])
    return " and ".join(hints)
