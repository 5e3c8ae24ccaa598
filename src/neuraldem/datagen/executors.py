"""Where datagen runs its simulations: `executor=local|submitit_local|slurm` (conf/executor/).

- `local` (default): `workers` threads in the datagen process, each driving one serial solver run.
- `submitit_local`: each simulation in its own process, started through submitit's local executor
  (`executor.array_parallelism` at a time) on this machine: the Slurm path without a cluster.
- `slurm`: one Slurm job array through submitit, a task per simulation (`executor.partition`, `time_min`,
  `cpus_per_task`, `mem_gb`, `array_parallelism`, ...). `executor.dry_run=true` writes the sbatch script and
  the task list into the run folder instead of submitting; `executor.wait=false` submits and returns.

An array task runs the missing work of one simulation (`Pipeline.run`) and writes its record to
`<dataset>/records/<sim_id>.json`; the datagen that submitted it (the dataset's only writer) merges these
files into the manifest as they appear (neuraldem.datagen.records). Resume is the manifest's: kill the
datagen or its tasks, run the same command again, and only unfinished simulations run.
"""

from __future__ import annotations

import copy
import json
import logging
import math
import re
import shutil
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from neuraldem.config import checks
from neuraldem.data.integrity import writing_for
from neuraldem.data.manifest import SimRecord
from neuraldem.datagen.driver import DatagenOptions, Pipeline, plan, run_safely
from neuraldem.datagen.records import (
    add_to_ledger,
    drop_records,
    ledger_entry,
    read_record,
    remove_from_ledger,
    slurm_tasks_listed,
    write_record,
)
from neuraldem.errors import ConfigError, NeuraldemError

log = logging.getLogger("neuraldem.datagen")

KINDS = ("local", "submitit_local", "slurm")
_SUBMITIT_KEYS = {"kind", "array_parallelism", "time_min", "poll_s"}
KEYS = {
    "local": {"kind"},
    "submitit_local": _SUBMITIT_KEYS,
    "slurm": _SUBMITIT_KEYS | {"partition", "cpus_per_task", "mem_gb", "account", "qos", "job_name", "setup",
                               "additional_parameters", "dry_run", "wait"},
}
# sbatch options the script gets from named settings (or that submitit sets itself): not in additional_parameters
_RESERVED_SBATCH = {"array", "output", "error", "partition", "time", "cpus-per-task", "mem", "account", "qos",
                    "job-name", "signal", "open-mode"}
INSTALL_HINT = "pip install 'neuraldem[sweep]' (or pip install submitit)"


@dataclass(frozen=True)
class ExecutorSettings:
    kind: str = "local"
    array_parallelism: int = 1
    time_min: int = 60
    poll_s: float = 1.0
    partition: str | None = None
    cpus_per_task: int = 1
    mem_gb: float | None = None
    account: str | None = None
    qos: str | None = None
    job_name: str = "neuraldem-datagen"
    setup: tuple[str, ...] = ()
    additional_parameters: dict[str, Any] = field(default_factory=dict)
    dry_run: bool = False
    wait: bool = True

    @classmethod
    def from_config(cls, cfg: Any, key: str = "executor") -> ExecutorSettings:
        """The `executor` config group, every value checked (a bad one is refused naming its key)."""
        if cfg is None:
            return cls()
        values = OmegaConf.to_container(cfg, resolve=True) if OmegaConf.is_config(cfg) else dict(cfg)
        if not isinstance(values, dict):
            raise ConfigError(f"config value {key}={values!r} is invalid: choose executor={'|'.join(KINDS)}")
        kind = checks.one_of(f"{key}.kind", values.get("kind"), KINDS)
        checks.known_keys(key, values, KEYS[kind])
        s: dict[str, Any] = {"kind": kind}
        if "array_parallelism" in values:
            s["array_parallelism"] = checks.positive_int(f"{key}.array_parallelism", values["array_parallelism"])
        if "time_min" in values:
            s["time_min"] = checks.positive_int(f"{key}.time_min", values["time_min"])
        if "poll_s" in values:
            s["poll_s"] = checks.number(f"{key}.poll_s", values["poll_s"], lo=0.05, hi=600.0)
        if "cpus_per_task" in values:
            s["cpus_per_task"] = checks.positive_int(f"{key}.cpus_per_task", values["cpus_per_task"])
        if values.get("mem_gb") is not None:
            s["mem_gb"] = checks.positive(f"{key}.mem_gb", values["mem_gb"])
        for name in ("partition", "account", "qos", "job_name"):
            if values.get(name) is not None:
                s[name] = _word(f"{key}.{name}", values[name])
        if "setup" in values:
            s["setup"] = _lines(f"{key}.setup", values["setup"])
        if "additional_parameters" in values:
            s["additional_parameters"] = _sbatch_options(f"{key}.additional_parameters",
                                                         values["additional_parameters"])
        for name in ("dry_run", "wait"):
            if name in values:
                s[name] = checks.boolean(f"{key}.{name}", values[name])
        return cls(**s)


def _word(key: str, value: Any) -> str:
    if not isinstance(value, (str, int)) or isinstance(value, bool) or not re.fullmatch(r"[\w.,:@+=-]+", str(value)):
        raise ConfigError(f"config value {key}={value!r} is invalid: must be a name (letters, digits, . , : - _) "
                          f"or null (override it, e.g. {key}=...)")
    return str(value)


def _lines(key: str, value: Any) -> tuple[str, ...]:
    if isinstance(value, str) or not isinstance(value, Sequence) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"config value {key}={value!r} is invalid: must be a list of shell lines, e.g. "
                          f"{key}='[\"module load liggghts\"]'")
    return tuple(value)


def _sbatch_options(key: str, value: Any) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise ConfigError(f"config value {key}={value!r} is invalid: must be a mapping of sbatch options, e.g. "
                          f"{key}='{{constraint: skylake}}'")
    out = {}
    for name, v in value.items():
        flag = str(name).replace("_", "-")
        if flag in _RESERVED_SBATCH:
            raise ConfigError(f"config value {key}.{name} is invalid: {flag} is set by executor.* settings or by "
                              "submitit itself (use executor.partition, time_min, cpus_per_task, mem_gb, account, "
                              "qos, job_name)")
        if not isinstance(v, (str, int, float, bool)):
            raise ConfigError(f"config value {key}.{name}={v!r} is invalid: must be a single value")
        out[str(name)] = v
    return out


def require_backend(s: ExecutorSettings) -> None:
    """What an executor needs on this machine, refused in one line before anything runs."""
    if s.kind == "local":
        return
    try:
        import submitit  # noqa: F401
    except ImportError:
        raise ConfigError(f"executor={s.kind} needs the submitit package, which is not installed: {INSTALL_HINT}; "
                          "or use executor=local") from None
    if s.kind == "slurm" and not s.dry_run:
        missing = [tool for tool in ("sbatch", "srun") if shutil.which(tool) is None]
        if missing:
            verb = "is" if len(missing) == 1 else "are"
            raise ConfigError("executor=slurm submits with sbatch and runs tasks with srun, and "
                              f"{' and '.join(missing)} {verb} not on PATH here: run this on a Slurm login node, or "
                              "use executor=submitit_local (separate processes on this machine) or "
                              "executor.dry_run=true (writes the sbatch script only)")


def slurm_parameters(s: ExecutorSettings) -> dict[str, Any]:
    """The settings as submitit's SlurmExecutor parameters (`update_parameters`)."""
    params: dict[str, Any] = {"job_name": s.job_name, "time": s.time_min, "cpus_per_task": s.cpus_per_task,
                              "array_parallelism": s.array_parallelism}
    if s.mem_gb is not None:
        params["mem"] = f"{math.ceil(s.mem_gb * 1024)}M"
    for name in ("partition", "account", "qos"):
        if getattr(s, name) is not None:
            params[name] = getattr(s, name)
    if s.setup:
        params["setup"] = list(s.setup)
    if s.additional_parameters:
        params["additional_parameters"] = dict(s.additional_parameters)
    return params


def sbatch_script(folder: Path, s: ExecutorSettings, n_tasks: int) -> str:
    """The sbatch script that submitit's SlurmExecutor submits for an array of `n_tasks` simulations.

    submitit makes this text only on its way to calling sbatch (`_make_submission_file_text`, with the array
    size in `parameters["map_count"]` as its own array submission sets it), and its SlurmExecutor refuses to be
    made where there is no srun. This function is the one place that reaches into submitit's private API."""
    from submitit.slurm.slurm import SlurmExecutor

    class ScriptOnly(SlurmExecutor):  # type: ignore[misc]
        @classmethod
        def affinity(cls) -> int:
            return 2  # "a Slurm cluster is here": writing the script needs none

    ex = ScriptOnly(folder)
    ex.update_parameters(**slurm_parameters(s))
    ex.parameters["map_count"] = n_tasks
    return ex._make_submission_file_text(ex._submitit_command_str, "dry-run")


def make_runner(s: ExecutorSettings, run_dir: Path) -> SubmititRunner | None:
    """The runner of an executor (None: datagen's own `workers` threads)."""
    return None if s.kind == "local" else SubmititRunner(s, Path(run_dir) / "submitit")


# ---- in the array task
def run_task(pipe: Pipeline, rec: SimRecord) -> str:
    """One array task: the missing work of one simulation, its record written to `<dataset>/records/`. A
    solver stopped from outside raises (no record: the simulation stays pending)."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    with writing_for(pipe.dataset_dir):
        new = run_safely(pipe.run, rec)
    write_record(pipe.dataset_dir, new)
    return new.status


def detached(pipe: Pipeline) -> Pipeline:
    """A copy of `pipe` to pickle for the tasks: its `data` config resolved into a plain one (no links to the
    Hydra run it came from), the solver version looked up once here instead of in every task."""
    pipe.solver_record()
    out = copy.copy(pipe)
    cfg = getattr(pipe, "cfg", None)
    if OmegaConf.is_config(cfg):
        out.cfg = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))  # type: ignore[attr-defined]
    return out


# ---- in the submitting datagen
@dataclass
class SubmititRunner:
    """executor=submitit_local|slurm: a task per simulation, results merged as their record files appear."""

    settings: ExecutorSettings
    folder: Path  # submitit's folder: pickled tasks, their logs
    array_id: str = ""  # the Slurm array once submitted

    def describe(self) -> str:
        s = self.settings
        if s.kind == "slurm":
            where = f"partition {s.partition}" if s.partition else "default partition"
            return f"on Slurm, {where} ({s.array_parallelism} at a time; logs in {self.folder})"
        return f"as submitit local tasks ({s.array_parallelism} at a time; logs in {self.folder})"

    def executor(self) -> Any:
        import submitit

        s = self.settings
        if s.kind == "slurm":
            ex = submitit.SlurmExecutor(folder=self.folder)
            ex.update_parameters(**slurm_parameters(s))
        else:
            ex = submitit.LocalExecutor(folder=self.folder)
            ex.update_parameters(timeout_min=s.time_min)
        return ex

    def run(self, pipe: Pipeline, todo: list[SimRecord], finished: Callable[[SimRecord], None]) -> None:
        if not todo:
            return
        s = self.settings
        ex = self.executor()
        task_pipe = detached(pipe)
        rows = {r.sim_id: r for r in todo}
        queue = list(todo)
        running: dict[str, Any] = {}  # sim_id -> submitit job
        lost: dict[str, str] = {}
        try:
            if s.kind == "slurm":
                jobs = ex.map_array(run_task, [task_pipe] * len(queue), queue)
                array_id = self.array_id = str(jobs[0].job_id).split("_")[0]
                add_to_ledger(pipe.dataset_dir, [ledger_entry("slurm", array_id, list(rows), self.folder)])
                running = {r.sim_id: job for r, job in zip(queue, jobs, strict=True)}
                queue = []
                what = f"Slurm job array {array_id}" if len(running) > 1 else f"Slurm job {array_id}"
                log.info("%s: submitted %s (%d simulation(s))", pipe.name, what, len(running))
                if not s.wait:
                    print(f"submitted {what} ({len(running)} simulation(s), at most "
                          f"{s.array_parallelism} at a time; logs in {self.folder}): run the same datagen command "
                          "again when it has ended (squeue --jobs " + array_id + ") to merge the results")
                    return
            while queue or running:
                while s.kind != "slurm" and queue and len(running) < s.array_parallelism:
                    rec = queue.pop(0)
                    job = ex.submit(run_task, task_pipe, rec)
                    add_to_ledger(pipe.dataset_dir, [ledger_entry(s.kind, job.job_id, [rec.sim_id], self.folder)])
                    running[rec.sim_id] = job
                if not self._collect(pipe, rows, running, finished, lost):
                    time.sleep(s.poll_s)
        except KeyboardInterrupt:  # Ctrl-C stops the tasks too (executor.wait=false leaves an array running)
            if s.kind == "slurm" and running:
                subprocess.run(["scancel", array_id], check=False)
            else:
                for job in running.values():
                    job.cancel(check=False)
            raise
        if s.kind == "slurm":
            remove_from_ledger(pipe.dataset_dir, {array_id})
        if lost:
            shown = "; ".join(f"{k}: {v}" for k, v in list(lost.items())[:3])
            raise NeuraldemError(f"{len(lost)} of {len(todo)} simulation(s) ended without a result and stay "
                                 f"pending ({shown})",
                                 "run the same command again to resume them (finished simulations are kept)")

    def _collect(self, pipe: Pipeline, rows: dict[str, SimRecord], running: dict[str, Any],
                 finished: Callable[[SimRecord], None], lost: dict[str, str]) -> bool:
        """Merge the records of tasks that finished; note tasks that ended without one. True if any did."""
        ended = {sim_id for sim_id, job in running.items() if job.done()}  # before the records are read
        if self.settings.kind == "slurm" and len(ended) < len(running):
            listed = slurm_tasks_listed(self.array_id)  # done() needs sacct to see a task that left no result
            if listed is not None:
                ended |= {sim_id for sim_id, job in running.items() if str(job.job_id) not in listed}
        gone = []
        for sim_id in list(running):
            rec = read_record(pipe.dataset_dir, sim_id, rows[sim_id], discard=True)
            if rec is not None:
                finished(rec)  # saved in the manifest ...
                drop_records(pipe.dataset_dir, [sim_id])  # ... before the record file goes
            elif sim_id in ended:
                lost[sim_id] = task_failure(running[sim_id])
            else:
                continue
            gone.append(running.pop(sim_id))
        if gone and self.settings.kind != "slurm":
            remove_from_ledger(pipe.dataset_dir, {str(job.job_id) for job in gone})
        return bool(gone)


_ERROR_LINE = re.compile(r"^[A-Za-z_][\w.]*(Error|Exception|Interrupt|Interrupted|Exit)\b")


def task_failure(job: Any) -> str:
    """Why a task ended without a record: the last exception line of its log, or that it was killed."""
    path = Path(job.paths.stderr)
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        lines = []
    last = next((ln.strip() for ln in reversed(lines) if _ERROR_LINE.match(ln.strip())), "")
    return f"{last or 'the task was killed'} (log: {path})"


# ---- executor.dry_run=true
def dry_run(pipe: Pipeline, opts: DatagenOptions, s: ExecutorSettings, run_dir: Path) -> Path | None:
    """Write the sbatch script and the task list a Slurm datagen would submit into `run_dir/dry_run`; submit
    nothing and write nothing into the dataset. Returns the script's path (None when nothing is left to run)."""
    m, todo, _ = plan(pipe, opts)
    if not todo:
        print(f"dry run: {pipe.name}: all {opts.n_sims} simulations are finished, nothing to submit")
        return None
    out = Path(run_dir) / "dry_run"
    out.mkdir(parents=True, exist_ok=True)
    script = out / "array.sbatch"
    script.write_text(sbatch_script(Path(run_dir) / "submitit", s, len(todo)))
    tasks = out / "tasks.json"
    tasks.write_text(json.dumps({"dataset": str(pipe.dataset_dir), "n_sims": opts.n_sims, "tasks": [
        {"array_index": k, "sim_id": r.sim_id, "params": r.params} for k, r in enumerate(todo)]}, indent=1))
    print(f"dry run: {len(todo)} of {opts.n_sims} simulations of {m.name} would run as Slurm array "
          f"0-{len(todo) - 1}%{min(len(todo), s.array_parallelism)}; nothing submitted")
    print(f"sbatch script: {script}")
    print(f"task list: {tasks}")
    return script
