"""Evaluated hopper training runs as benchmark points: their errors (`<run>/evaluation/metrics.json`, written
by `neuraldem evaluate` or `neuraldem train ... evaluate=true`), their size (from the checkpoint and the run's
config) and their measured time to answer one trajectory.

A run folder is a folder holding `checkpoints/` (what `neuraldem train` makes). A run without its
evaluation is an error unless skipped on purpose: a chart silently missing a model would mislead.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from neuraldem.bench.choices import pick_record
from neuraldem.bench.timing import SYSTEM_CLOCK, Clock, Timing, time_call, torch_threads
from neuraldem.errors import DataError
from neuraldem.eval.checkpoints import read_checkpoint
from neuraldem.paths import data_dir
from neuraldem.scenes.hopper.analysis.scoring import HOPPER_ERRORS
from neuraldem.scenes.hopper.bench.surrogate import answer, full_question, load_surrogate, surrogate_dataset

METRICS = Path("evaluation") / "metrics.json"
# practitioner's quantities: aggregate key in metrics.json -> chart label
EVALUATE_HINT = ("evaluate it with `neuraldem evaluate ckpt={run}/checkpoints/last.ckpt "
                 "hydra.run.dir={run}/evaluation`, or pass skip_unevaluated=true")


@dataclass
class EvaluatedRun:
    run_dir: Path
    checkpoint: Path
    data_name: str
    dataset: Path
    split: str
    conditioning: list[str]
    errors: dict[str, float]
    size: dict[str, Any]
    timing: dict[str, Any] = field(default_factory=dict)
    label: str = ""  # the run folder relative to the folder it was found under

    def as_point(self) -> dict[str, Any]:
        """A chart point: method, label, errors, size and time to answer (median wall seconds)."""
        return {"method": "surrogate", "label": self.label, "run_dir": str(self.run_dir),
                "checkpoint": str(self.checkpoint), "data_name": self.data_name, "split": self.split,
                "conditioning": self.conditioning, "errors": self.errors, "size": self.size,
                "time_to_answer_s": self.timing.get("median_wall_s"), "cpu_s": self.timing.get("median_cpu_s"),
                "timing": self.timing}


def run_folders(folders: list[Path]) -> tuple[list[Path], list[Path]]:
    """(evaluated, unevaluated) run folders under `folders` (each may itself be a run folder)."""
    evaluated: set[Path] = set()
    unevaluated: set[Path] = set()
    for folder in folders:
        folder = Path(folder)
        if not folder.is_dir():
            raise DataError(f"runs={folder}: no such folder: pass folders that hold training runs")
        for ckpts in folder.rglob("checkpoints"):
            if ckpts.is_dir():
                run = ckpts.parent
                (evaluated if (run / METRICS).is_file() else unevaluated).add(run)
        evaluated.update(p.parent.parent for p in folder.rglob(str(METRICS)))
        if (folder / METRICS).is_file():
            evaluated.add(folder)
    return sorted(evaluated), sorted(unevaluated - evaluated)


def read_run(run_dir: Path) -> EvaluatedRun | None:
    """A hopper run's errors and size; None for a run of another kind (e.g. a fluidized-bed model)."""
    path = run_dir / METRICS
    try:
        result = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise DataError(f"{path} is not valid JSON ({err}): re-run the evaluation") from None
    aggregate = result.get("aggregate")
    if not isinstance(aggregate, dict):
        raise DataError(f"{path} has no 'aggregate' field: it was not written by neuraldem.evaluate; re-run "
                        "the evaluation")
    if "drainage_mae_s" not in aggregate:
        return None  # another scene's metrics (kept out of hopper charts)
    if "drainage_t95_pct_of_mean" not in aggregate:
        raise DataError(f"{path} was scored with metrics older than drainage t95 (docs/metrics.md): re-run the "
                        "evaluation with this neuraldem (neuraldem evaluate ckpt=...)")
    missing = [k for k in HOPPER_ERRORS if k not in aggregate]
    if missing:
        raise DataError(f"{path}: field 'aggregate' lacks {missing}: re-run the evaluation with this neuraldem")
    ckpt = locate_checkpoint(run_dir, result)
    c = read_checkpoint(ckpt)
    hp = c.hyper_parameters
    meta, net = hp.get("metadata") or {}, hp.get("net") or {}
    params = c.net_parameters
    size = {"parameters": int(params), "dim": net.get("dim"), "depth": net.get("depth"),
            "n_latent_tokens": net.get("n_latent_tokens"), "train_queries": train_queries(run_dir)}
    return EvaluatedRun(run_dir=run_dir, checkpoint=ckpt, data_name=str(meta.get("data_name")),
                        dataset=Path(result.get("dataset", "")), split=str(result.get("split")),
                        conditioning=list(result.get("conditioning", [])),
                        errors={k: float(aggregate[k]) for k in HOPPER_ERRORS}, size=size)


def locate_checkpoint(run_dir: Path, result: dict[str, Any]) -> Path:
    """The evaluated checkpoint: its recorded path, else the file of that name in the run's checkpoints/
    (a run folder moved after evaluation)."""
    recorded = Path(str(result.get("checkpoint", "")))
    for candidate in (recorded, run_dir / "checkpoints" / recorded.name):
        if candidate.is_file():
            return candidate
    raise DataError(f"{run_dir / METRICS}: field 'checkpoint' = {str(recorded)!r} does not exist (nor in "
                    f"{run_dir / 'checkpoints'}): restore the checkpoint or re-run the evaluation")


def train_queries(run_dir: Path) -> int | None:
    """Query points per training sample, from the run's saved Hydra config (None when not recorded)."""
    path = run_dir / ".hydra" / "config.yaml"
    if not path.is_file():
        return None
    value = OmegaConf.select(OmegaConf.load(path), "data.datamodule.n_queries", throw_on_resolution_failure=False)
    return int(value) if isinstance(value, int) else None


def run_label(run_dir: Path, folders: list[Path]) -> str:
    """The run folder relative to the `runs=` folder it lies in (e.g. `multirun_.../3`), else its name."""
    for folder in folders:
        try:
            rel = run_dir.resolve().relative_to(Path(folder).resolve())
        except ValueError:
            continue
        return str(rel) if rel.parts else run_dir.name
    return run_dir.name


def collect_runs(folders: list[Path], skip_unevaluated: bool = False) -> tuple[list[EvaluatedRun], list[str]]:
    """Every evaluated hopper run under `folders`, and notes on what was left out and why."""
    evaluated, unevaluated = run_folders(folders)
    notes = []
    if unevaluated and not skip_unevaluated:
        first = unevaluated[0]
        raise DataError(f"{len(unevaluated)} run folder(s) without {METRICS} (e.g. {first}): "
                        + EVALUATE_HINT.format(run=first))
    notes += [f"{run}: not evaluated (skipped)" for run in unevaluated]
    runs = []
    for run_dir in evaluated:
        run = read_run(run_dir)
        if run is None:
            notes.append(f"{run_dir}: not a hopper run (skipped)")
        else:
            run.label = run_label(run_dir, folders)
            runs.append(run)
    if not runs:
        raise DataError(f"no evaluated hopper run under {[str(f) for f in folders]}: train with "
                        "`neuraldem train experiment=hopper_micro` (evaluates at the end) or evaluate "
                        "a checkpoint with `neuraldem evaluate ckpt=...`")
    return runs, notes


def time_to_answer(run: EvaluatedRun, repeats: int, threads: int, dataset_dir: Path | None = None,
                   clock: Clock = SYSTEM_CLOCK) -> Timing:
    """Seconds for the run's model to answer one full question: every snapshot time at every initial particle
    position of the first test simulation of its split (median of `repeats` after one warm-up call)."""
    surrogate = load_surrogate(run.checkpoint)
    dataset = dataset_dir or (run.dataset if (run.dataset / "manifest.json").is_file() else None)
    dataset, m = surrogate_dataset(surrogate, dataset, data_dir() / "datasets")
    q = full_question(m, dataset, pick_record(m, run.split, None), surrogate.predictor.norm)
    with torch_threads(threads):
        timing, _ = time_call(lambda: answer(surrogate, q), repeats, warmup=1, clock=clock)
    timing.notes.update(threads=threads, question=q.describe(), load_s=surrogate.load_s)
    return timing
