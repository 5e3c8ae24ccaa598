"""The resumable datagen loop shared by all scenes: manifest, parameter table, workers, progress.

A scene plugs in a `Pipeline` (how to run and store one simulation, how to split). The loop:
load or create the manifest (refusing a dataset made with a different scene), merge the results array tasks left
in record files (neuraldem.datagen.records), extend the parameter table, run every unfinished simulation through
a `SimRunner` (by default `workers` threads, each driving one serial solver process; neuraldem.datagen.executors
runs them as submitit/Slurm array tasks), and save the manifest after every finished simulation. Killed and
restarted, it redoes only unfinished work.
"""

from __future__ import annotations

import json
import logging
import shutil
from collections import Counter
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from tqdm import tqdm

from neuraldem.data.integrity import command_line, dataset_lock
from neuraldem.data.manifest import MANIFEST_NAME, Manifest, SimRecord
from neuraldem.data.schema import TMP_SUFFIX, sha256
from neuraldem.datagen.records import drop_records, earlier_jobs_error, merge_records, still_running
from neuraldem.errors import ConfigError, DataError, NeuraldemError, SolverInterrupted

log = logging.getLogger(__name__)


class Pipeline(Protocol):
    kind: str
    name: str
    dataset_dir: Path

    def scene_record(self) -> dict[str, Any]:
        """Everything that determines the data; a dataset made with another scene is refused."""

    def solver_record(self) -> dict[str, str]: ...

    def parameter_record(self) -> dict[str, Any]: ...

    def new_parameters(self, n: int, batch: int) -> list[dict[str, float]]: ...

    def prepare(self, manifest: Manifest) -> None:
        """Adjust an opened manifest to the current settings that do not invalidate simulations."""

    def incomplete(self, record: SimRecord) -> bool:
        """Scene-specific work still missing for a finished simulation (e.g. its characterization)."""

    def run_order(self, todo: list[SimRecord], manifest: Manifest) -> list[SimRecord]:
        """The order in which the pending simulations run (so that a partly generated set is useful)."""

    def run(self, record: SimRecord) -> SimRecord:
        """Do what is missing for one simulation (run, store, score, characterize); return the updated
        record (never raise for solver trouble)."""

    def splits(self, manifest: Manifest) -> dict[str, dict[str, list[str]]]: ...


@dataclass
class DataConfigPipeline:
    """What every scene's pipeline starts from: its `data` config, whose name and folder identify the dataset."""

    cfg: Any  # the `data` config (DictConfig)
    name: str = field(init=False)
    dataset_dir: Path = field(init=False)

    def __post_init__(self) -> None:
        self.name = str(self.cfg.name)
        self.dataset_dir = Path(self.cfg.dataset_dir)


@dataclass
class DatagenOptions:
    n_sims: int
    workers: int
    retry_failed: bool = False
    progress: bool = True
    first: tuple[str, ...] = ()  # sim ids run before the scene's own order (e.g. a long test trajectory)
    runner: SimRunner | None = None  # where the simulations run; default: `workers` threads (ThreadRunner)


def open_manifest(pipe: Pipeline) -> Manifest:
    path = pipe.dataset_dir / MANIFEST_NAME
    scene = json.loads(json.dumps(pipe.scene_record()))  # normalise (tuples -> lists) as stored
    if not path.exists():
        return Manifest(name=pipe.name, kind=pipe.kind, scene=scene, solver=pipe.solver_record(),
                        parameters=pipe.parameter_record())
    m = Manifest.load(pipe.dataset_dir)
    if m.kind != pipe.kind or m.scene != scene:
        diff = sorted(_diff_keys(m.scene, scene)) or ["kind"]
        raise DataError(f"dataset {pipe.dataset_dir} was made with a different scene (differs in {diff}): "
                        "choose another data.name for the new scene, or delete that folder to regenerate")
    return m


def _diff_keys(a: Any, b: Any, prefix: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            out += _diff_keys(a.get(k), b.get(k), f"{prefix}{k}.")
        return out
    return [] if a == b else [prefix.rstrip(".")]


def extend_table(m: Manifest, pipe: Pipeline, n_sims: int) -> None:
    missing = n_sims - len(m.simulations)
    if missing <= 0:
        return
    batch = len({r.diagnostics.get("batch", 0) for r in m.simulations}) if m.simulations else 0
    start = len(m.simulations)
    for k, params in enumerate(pipe.new_parameters(missing, batch)):
        i = start + k
        m.simulations.append(SimRecord(sim_id=f"sim_{i:04d}", index=i, params=params,
                                       diagnostics={"batch": batch}))


def simulation_done(rec: SimRecord, dataset_dir: Path) -> bool:
    """The solver part is finished: ok/clogged with its file present and unchanged."""
    if rec.status not in ("ok", "clogged") or rec.file is None:
        return False
    path = dataset_dir / rec.file
    if not path.is_file() or sha256(path) != rec.sha256:
        log.warning("%s: %s missing or changed since it was written, running it again", rec.sim_id, path)
        return False
    return True


def needs_run(rec: SimRecord, pipe: Pipeline, retry_failed: bool) -> bool:
    if rec.status == "failed":
        return retry_failed
    return not simulation_done(rec, pipe.dataset_dir) or pipe.incomplete(rec)


def remove_partials(dataset_dir: Path) -> None:
    """Temporary files of writes killed mid-way are never read; delete them."""
    for p in dataset_dir.rglob(f"*{TMP_SUFFIX}"):
        p.unlink(missing_ok=True)


def generate(pipe: Pipeline, opts: DatagenOptions) -> Manifest:
    """Run what the dataset lacks, as the only writer of the dataset (a second datagen is refused)."""
    with dataset_lock(pipe.dataset_dir, command_line("neuraldem.datagen")):
        return _generate(pipe, opts)


def plan(pipe: Pipeline, opts: DatagenOptions) -> tuple[Manifest, list[SimRecord], list[str]]:
    """Open the manifest, merge the results array tasks left in record files, adjust it to the current settings,
    extend the table to `n_sims`, and list the simulations still to run in the order they run; also returns the
    record files read (delete them once the manifest is saved). Changes nothing on disk (a dry run calls this)."""
    m = open_manifest(pipe)
    merged, ignored = merge_records(m, pipe.dataset_dir)
    pipe.prepare(m)
    extend_table(m, pipe, opts.n_sims)
    todo = [r for r in m.simulations[: opts.n_sims] if needs_run(r, pipe, opts.retry_failed)]
    for rec in todo:
        if rec.status == "failed":  # retried from scratch
            rec.status, rec.reason = "pending", ""
    todo = put_first(pipe.run_order(todo, m), opts.first, m.simulations[: opts.n_sims])
    return m, todo, merged + ignored


def _generate(pipe: Pipeline, opts: DatagenOptions) -> Manifest:
    pipe.dataset_dir.mkdir(parents=True, exist_ok=True)
    refuse_while_earlier_jobs_run(pipe)
    remove_partials(pipe.dataset_dir)
    m, todo, read = plan(pipe, opts)
    done = opts.n_sims - len(todo)
    m.splits = pipe.splits(m)
    m.save(pipe.dataset_dir)
    drop_records(pipe.dataset_dir, read)
    runner = opts.runner or ThreadRunner(opts.workers)
    log.info("%s: %d simulations, %d finished, %d to run %s", pipe.name, opts.n_sims, done, len(todo),
             runner.describe())
    counts = Counter(r.status for r in m.simulations[: opts.n_sims] if r not in todo)
    bar = tqdm(total=opts.n_sims, initial=done, desc=pipe.name, unit="sim", disable=not opts.progress,
               dynamic_ncols=True)

    def finished(new: SimRecord) -> None:
        row = next(k for k, r in enumerate(m.simulations) if r.sim_id == new.sim_id)
        m.simulations[row] = new
        counts[new.status] += 1
        m.splits = pipe.splits(m)
        m.save(pipe.dataset_dir)
        bar.update(1)
        bar.set_postfix(dict(counts))
        if new.status != "ok":
            bar.write(f"{new.sim_id}: {new.status}: {new.reason}")

    try:
        runner.run(pipe, todo, finished)
    finally:
        bar.close()
    return m


def refuse_while_earlier_jobs_run(pipe: Pipeline) -> None:
    """Array jobs of an earlier datagen that may still run: merge what they finished, then refuse to start
    (a second run of their simulations would write the same folders)."""
    running, unknown = still_running(pipe.dataset_dir)
    if not running and not unknown:
        return
    merged: list[str] = []
    if (pipe.dataset_dir / MANIFEST_NAME).exists():
        m = open_manifest(pipe)
        merged, ignored = merge_records(m, pipe.dataset_dir)
        if merged:
            m.splits = pipe.splits(m)
            m.save(pipe.dataset_dir)
        drop_records(pipe.dataset_dir, merged + ignored)
    raise earlier_jobs_error(pipe.dataset_dir, running, unknown, len(merged))


class SimRunner(Protocol):
    """Runs simulations somewhere (threads here, array tasks elsewhere) and reports each finished one."""

    def describe(self) -> str:
        """How they run, for the log line (e.g. `on 2 worker(s)`)."""

    def run(self, pipe: Pipeline, todo: list[SimRecord], finished: Callable[[SimRecord], None]) -> None:
        """Run every record of `todo` (`pipe.run`), calling `finished` with each resulting record as it comes
        (in this process, one at a time). A simulation stopped from outside stays pending and ends the run with
        an error once the others are in."""


@dataclass
class ThreadRunner:
    """executor=local: `workers` threads in this process, each driving one serial solver process."""

    workers: int

    def describe(self) -> str:
        return f"on {self.workers} worker(s)"

    def run(self, pipe: Pipeline, todo: list[SimRecord], finished: Callable[[SimRecord], None]) -> None:
        interrupted: SolverInterrupted | None = None
        with ThreadPoolExecutor(max_workers=self.workers) as pool:
            pending: dict[Future[SimRecord], SimRecord] = {pool.submit(run_safely, pipe.run, r): r for r in todo}
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    pending.pop(fut)
                    if fut.cancelled():
                        continue
                    try:
                        new = fut.result()
                    except SolverInterrupted as err:  # stays pending; queued ones never start, running ones finish
                        interrupted = interrupted or err
                        for queued in pending:
                            queued.cancel()
                        continue
                    finished(new)
        if interrupted is not None:
            raise interrupted


def put_first(todo: list[SimRecord], first: tuple[str, ...], table: list[SimRecord]) -> list[SimRecord]:
    """`todo` with the simulations named in `first` moved to the front (in that order); the rest keep the
    scene's order. Names outside the table are a config error (a typo would otherwise do nothing)."""
    unknown = sorted(set(first) - {r.sim_id for r in table})
    if unknown:
        raise ConfigError(f"config value first={list(first)} names {unknown}, which are not among the "
                          f"{len(table)} simulations: use ids sim_0000 .. sim_{len(table) - 1:04d}")
    return sorted(todo, key=lambda r: first.index(r.sim_id) if r.sim_id in first else len(first))


def run_safely(fn: Callable[[SimRecord], SimRecord], rec: SimRecord) -> SimRecord:
    """A simulation that breaks in an unexpected way is recorded as failed; the others go on. A solver
    killed from outside is not a failure: it stops the job and the simulation stays pending."""
    try:
        return fn(rec)
    except SolverInterrupted:
        raise  # killed from outside: unfinished, stays pending, the job stops
    except NeuraldemError as err:
        return _failed(rec, str(err))
    except Exception as err:
        log.exception("%s: unexpected error", rec.sim_id)
        return _failed(rec, f"internal error {type(err).__name__}: {err}")


def _failed(rec: SimRecord, reason: str) -> SimRecord:
    rec.status, rec.reason = "failed", reason
    return rec


def fresh_dir(path: Path) -> Path:
    """An empty run folder (a killed run's leftovers are removed first)."""
    if path.exists():
        shutil.rmtree(path)
    path.mkdir(parents=True)
    return path
