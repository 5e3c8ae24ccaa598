"""DPMFoam against the fluidized-bed rollout on the same scene and machine, side by side in one run.

`neuraldem bench fb_speed ckpt=CKPT [dataset=DIR] [sim=SIM_ID] [repeats=3]
[solver_repeats=3] [sim_seconds=0.1] [rollout_steps=N] [threads=[1,N]] [runtime=[torch,onnx]] [reuse_dataset=true]
[rollout.rollout_noise=X] [rollout.mirror_alternate=true|false] [out=PATH]` writes
results/fluidized_bed/speed/fb_speed.json, .md and .png. Of the rollout options it takes those that change a step's
cost (`STEP_COST_OPTIONS`).

The unit both are compared in is the cost of one simulated second of the bed. The solver: fresh DPMFoam runs
of one trajectory of the checkpoint's dataset (its scene, inlet velocity and start-packing seed, through
`scenes.fluidized_bed.solver.runner.run_fluidized_bed`, the path datagen used): the dataset's spin-up plus
`sim_seconds=` stored seconds, wall and CPU time of the DPMFoam process divided by the seconds it simulated
(spin-up included, as the manifest's `cpu_s_per_simulated_s`); next to it the per-simulation costs the manifest
recorded at datagen.
The surrogate: `rollout_steps=` autoregressive steps (`scenes.fluidized_bed.rollout.rollout`, divergence check and
particle re-sampling included) from snapshot 1 of the same trajectory, divided by the seconds they span, at
each `threads=` setting and `runtime=` (torch, or the net's calls in ONNX Runtime, `models.operator_onnx`; the
one-time export is not timed). Ratios are solver / surrogate of the medians over repeats.
"""

from __future__ import annotations

import os
import shutil
import statistics
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neuraldem.bench import plots
from neuraldem.bench.choices import default_workdir, pick_record
from neuraldem.bench.report import command_line, machine_info, resolve_out, warn_if_busy, write_results
from neuraldem.bench.timing import SYSTEM_CLOCK, Clock, Sample, Timing, side_by_side, time_call, torch_threads
from neuraldem.cli import add_trajectory_options, command_parser
from neuraldem.config import checks
from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.errors import ConfigError, DataError, SolverError
from neuraldem.eval.checkpoints import checkpoint_dataset
from neuraldem.paths import data_dir
from neuraldem.scenes.fluidized_bed.dataset.datagen import packing_seed
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.solver.runner import STATUS_OK, run_fluidized_bed
from neuraldem.scenes.fluidized_bed.solver.scene import BedScene
from neuraldem.scenes.fluidized_bed.surrogate.module import BedModule
from neuraldem.scenes.fluidized_bed.surrogate.options import RolloutOptions, add_arguments
from neuraldem.scenes.fluidized_bed.surrogate.rollout import (
    BedState,
    DivergenceLimits,
    ModelStepper,
    initial_state,
    rollout,
)
from neuraldem.scenes.fluidized_bed.surrogate.rollout_run import check_grid, load_fb_checkpoint

NAME = "fb_speed"
SOLVER_THREADS = 1  # DPMFoam runs serially, as in datagen
DEFAULT_SIM_SECONDS = 0.1
RECORDED = "dataset manifest: per-simulation costs recorded when the dataset was generated, not re-run"
TARGET_SPEEDUP = 500.0  # real time: the bed's rollout >= 500x DPMFoam's CPU time at one thread (docs/benchmarks.md)
# the rollout options that change what a step costs (the others change its numbers, not its work)
STEP_COST_OPTIONS = ("rollout_noise", "mirror_alternate")


def usable_cpus() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


@dataclass
class BedCase:
    """The trajectory both sides answer: the dataset's scene, one record's inlet velocity and packing."""

    dataset_dir: Path
    manifest: Manifest
    scene: BedScene
    record: SimRecord

    @property
    def velocity(self) -> float:
        return float(self.record.params["inlet_velocity"])

    @property
    def seed(self) -> int:
        return packing_seed(int(self.manifest.parameters.get("seed", 0)), self.record.index)

    @property
    def file(self) -> Path:
        return self.dataset_dir / str(self.record.file)


def bench_case(module: BedModule, ckpt: Path, dataset_dir: Path | None, sim_id: str | None) -> BedCase:
    """The checkpoint's dataset (checked to be of its scene) and the trajectory to time: `sim_id`, else the
    first test trajectory of the checkpoint's split, else the first usable one."""
    meta = module.metadata
    dataset_dir, m = checkpoint_dataset(meta, Path(ckpt), data_dir() / "datasets", dataset_dir)
    if m.kind != "fluidized_bed" or "fluidized_bed" not in m.scene:
        raise DataError(f"{dataset_dir}/manifest.json: kind={m.kind!r}, not a fluidized-bed dataset: pass the "
                        "dataset the checkpoint was trained on (dataset=)")
    scene = BedScene.from_config(m.scene["fluidized_bed"], f"{dataset_dir}/manifest.json scene.fluidized_bed")
    rec = pick_record(m, meta["split"], sim_id)
    if not rec.usable:
        raise DataError(f"simulation {rec.sim_id} of {dataset_dir} is not finished (status {rec.status}): pick "
                        "another with sim=")
    return BedCase(dataset_dir, m, scene, rec)


def check_sim_seconds(scene: BedScene, sim_seconds: float) -> float:
    """Stored seconds of the timed run: a positive multiple of the scene's snapshot interval."""
    checks.positive("sim_seconds", sim_seconds)
    steps = sim_seconds / scene.snapshot_interval
    if steps < 1 - 1e-9 or abs(steps - round(steps)) > 1e-6:
        raise ConfigError(f"sim_seconds={sim_seconds} is invalid: must be a positive multiple of the scene's "
                          f"snapshot interval {scene.snapshot_interval} s (e.g. sim_seconds="
                          f"{10 * scene.snapshot_interval:g})")
    return float(sim_seconds)


# ---- the solver

def solver_measured(case: BedCase, sim_seconds: float, repeats: int, workdir: Path,
                    keep: bool = False) -> Timing:
    """Fresh DPMFoam runs of the case (spin-up + `sim_seconds`), each in a new folder: wall and CPU time of
    the DPMFoam process per simulated second (spin-up included). Meshing (once per case) and reading the
    time directories into arrays (datagen's conversion step) are not counted."""
    scene = case.scene
    simulated = scene.spinup_time + sim_seconds
    samples, substeps = [], []
    for r in range(checks.positive_int("solver_repeats", repeats)):
        folder = Path(workdir) / f"repeat_{r}"
        if folder.exists():  # never resume an earlier run: each repeat is timed from scratch
            shutil.rmtree(folder)
        try:
            result = run_fluidized_bed(scene, case.velocity, sim_seconds, folder, case.seed)
        finally:
            if not keep:
                shutil.rmtree(folder, ignore_errors=True)
        if result.status != STATUS_OK:
            raise SolverError(f"DPMFoam run of {case.record.sim_id} ({case.velocity:g} m/s, {simulated:g} s) "
                              f"failed: {result.reason}")
        samples.append(Sample(result.cost["solver_wall_s"], result.cost["solver_cpu_s"]))
        if "mean_collision_substeps" in result.diagnostics:
            substeps.append(result.diagnostics["mean_collision_substeps"])
    per_run = Timing(samples, notes={"unit": "seconds per run"})
    return per_run.scaled(1.0 / simulated, unit="seconds per simulated second", simulated_s=simulated,
                          spinup_s=scene.spinup_time, stored_s=sim_seconds, solver_threads=SOLVER_THREADS,
                          per_run=per_run.as_dict(),
                          mean_collision_substeps=statistics.median(substeps) if substeps else None)


def solver_recorded(m: Manifest, dataset_dir: Path) -> Timing:
    """The per-simulation costs the manifest recorded at datagen, per simulated second (every usable run).
    Wall time is the DPMFoam process's where recorded (`solver_wall_s`), else the run's (meshing included)."""
    recs = [r for r in m.usable() if {"solver_cpu_s", "simulated_s", "wall_s"} <= set(r.cost)
            and r.cost["simulated_s"] > 0]
    if not recs:
        raise DataError(f"{dataset_dir}/manifest.json records no solver_cpu_s/simulated_s cost for any simulation: "
                        "drop reuse_dataset= to time DPMFoam here")
    wall = [r.cost.get("solver_wall_s", r.cost["wall_s"]) for r in recs]
    per_run = Timing([Sample(w, r.cost["solver_cpu_s"]) for w, r in zip(wall, recs, strict=False)], source=RECORDED)
    samples = [Sample(w / r.cost["simulated_s"], r.cost["solver_cpu_s"] / r.cost["simulated_s"])
               for w, r in zip(wall, recs, strict=False)]
    return Timing(samples, source=RECORDED, notes={
        "unit": "seconds per simulated second", "dataset": str(dataset_dir), "solver_threads": SOLVER_THREADS,
        "per_simulation": {**per_run.as_dict(), "unit": "seconds per run",
                           "simulated_s": [r.cost["simulated_s"] for r in recs]},
        "wall_source": "solver_wall_s" if all("solver_wall_s" in r.cost for r in recs) else
        "wall_s (DPMFoam + blockMesh + writeCellCentres) where solver_wall_s was not recorded",
        "note": "wall times were recorded with datagen's workers running side by side; compare CPU times"})


# ---- the surrogate

def surrogate_timing(module: BedModule, velocity: float, state: BedState, steps: int, repeats: int,
                     threads: int, seed: int = 0, limits: DivergenceLimits | None = None,
                     clock: Clock = SYSTEM_CLOCK, options: RolloutOptions | None = None,
                     runtime: str = "torch") -> Timing:
    """Median over `repeats` (after one untimed warm-up) of a `steps`-step rollout from `state` on `threads`
    threads of `runtime`, per simulated second. A rollout that diverges is timed over the steps it computed."""
    def once():
        stepper = ModelStepper(module, velocity, seed, options=options, runtime=runtime)
        return rollout(stepper, state, steps, limits, progress=False)

    with torch_threads(threads):
        per_run, r = time_call(once, repeats, warmup=1, clock=clock)
    computed = r.diverged_at if r.diverged_at is not None else r.steps_done
    simulated = computed * module.norm.dt
    notes = {"unit": "seconds per simulated second", "torch_threads": threads, "runtime": runtime,
             "steps_requested": steps,
             "steps_computed": computed, "simulated_s": simulated, "diverged_at": r.diverged_at,
             "divergence": r.divergence, "per_run": {**per_run.as_dict(), "unit": "seconds per rollout"}}
    return per_run.scaled(1.0 / simulated, **notes)


# ---- side by side

def surrogate_label(runtime: str, threads: int) -> str:
    return f"{runtime}, {threads} thread(s)"


def compare(solvers: dict[str, Timing], surrogates: dict[str, Timing]) -> list[dict[str, Any]]:
    """One row per (solver timing, surrogate setting): medians per simulated second and the speed-ups."""
    rows = []
    for label, solver in solvers.items():
        for setting, surrogate in surrogates.items():
            row = side_by_side([solver], surrogate, f"{label} vs surrogate ({setting})")
            rows.append({"solver": label, "surrogate": setting,
                         "surrogate_runtime": surrogate.notes.get("runtime", "torch"),
                         "surrogate_threads": surrogate.notes["torch_threads"], **row})
    return rows


def render_markdown(results: dict[str, Any], machine: dict[str, Any]) -> str:
    sur = results["surrogate"]
    first = next(iter(sur.values()))
    lines = [(f"Scene {results['scene']}, trajectory {results['sim_id']} (U0 = {results['inlet_velocity']:g} "
              f"m/s); {results['n_particles']} particles, {results['cells']} cells."),
             (f"Surrogate: {first['steps_computed']} rollout steps of {results['dt']:g} s from snapshot 1, medians "
              f"of {first['repeats']} repeats; checkpoint loaded once in {results['surrogate_load_s']:.2f} s "
              "(not counted)."),
             f"Machine: {machine.get('cpu_model')} ({machine.get('cpu_count')} cores); DPMFoam serial."]
    for label, s in results["solver"].items():
        if s["source"] == "measured":
            lines.append(f"{label}: {s['repeats']} fresh run(s) of {s['simulated_s']:g} s ({s['spinup_s']:g} s "
                         f"spin-up + {s['stored_s']:g} s), DPMFoam process only.")
        else:
            lines.append(f"{label}: median over {s['repeats']} trajectories of the dataset ({s['source']}).")
    lines += ["", "Seconds per simulated second (medians):", "",
              ("| solver | surrogate runtime | threads | solver wall | solver CPU | surrogate wall | "
               "surrogate CPU | speed-up (wall) | speed-up (CPU) |"),
              "|---|---|---|---|---|---|---|---|---|"]
    for r in results["side_by_side"]:
        lines.append(f"| {r['solver']} | {r.get('surrogate_runtime', 'torch')} | {r['surrogate_threads']} | "
                     f"{r['solver_wall_s']:.1f} | "
                     f"{r['solver_cpu_s']:.1f} | {r['surrogate_wall_s']:.3f} | {r['surrogate_cpu_s']:.3f} | "
                     f"{_x(r['speedup_wall'])} | {_x(r['speedup_cpu'])} |")
    if first.get("diverged_at") is not None:
        lines += ["", (f"The rollout diverged at step {first['diverged_at']} ({first['divergence']}); "
                       "timed over the steps it computed.")]
    return "\n".join(lines) + "\n"


def _x(v: float | None) -> str:
    return "n/a" if v is None else f"{v:,.0f}x"


def parse_runtimes(values: list[str] | None) -> list[str]:
    """runtime=: distinct runtimes, default torch and onnx (onnx only where ONNX Runtime is installed)."""
    from neuraldem.models.operator_onnx import resolve_runtime

    if not values:
        return list(dict.fromkeys(["torch", resolve_runtime("auto")]))
    out: list[str] = []
    for i, r in enumerate(values):
        if r not in ("torch", "onnx"):
            raise ConfigError(f"runtime[{i}]={r!r} is invalid: choose torch or onnx", "e.g. runtime=[torch,onnx]")
        resolve_runtime(r, f"runtime[{i}]")
        if r not in out:
            out.append(r)
    return out


def parse_threads(values: list[int] | None) -> list[int]:
    """threads=: distinct positive counts, default 1 and every usable core."""
    values = values or [1, usable_cpus()]
    out: list[int] = []
    for i, t in enumerate(values):
        checks.positive_int(f"threads[{i}]", t)
        if t not in out:
            out.append(t)
    return out


@dataclass
class Plan:
    """Everything fb_speed measures, checked and loaded (nothing timed yet)."""

    ckpt: Path
    module: BedModule
    load_s: float  # wall seconds to load the checkpoint (once per session: reported, not in the ratios)
    case: BedCase
    state: BedState
    steps: int
    threads: list[int]
    runtimes: list[str]
    repeats: int
    solver_repeats: int
    sim_seconds: float
    recorded: Timing | None
    reuse_dataset: bool
    workdir: Path
    keep_runs: bool = False
    seed: int = 0
    options: RolloutOptions = RolloutOptions()


def prepare(ckpt: Path, dataset_dir: Path | None, sim_id: str | None, repeats: int, solver_repeats: int,
            sim_seconds: float, rollout_steps: int | None, threads: list[int] | None, reuse_dataset: bool,
            workdir: Path, keep_runs: bool = False, seed: int = 0, options: RolloutOptions | None = None,
            runtimes: list[str] | None = None) -> Plan:
    """Check every option and input (one clear error for a bad one) before anything is timed."""
    checks.positive_int("repeats", repeats)
    checks.positive_int("solver_repeats", solver_repeats)
    if rollout_steps is not None:
        checks.positive_int("rollout_steps", rollout_steps)
    checks.positive_int("seed", seed, allow_zero=True)
    options = options or RolloutOptions()
    other = sorted(set(options.given()) - set(STEP_COST_OPTIONS))
    if other:
        raise ConfigError(f"rollout.{other[0]}= does not change what a step costs: fb_speed takes "
                          f"{', '.join(f'rollout.{n}=' for n in STEP_COST_OPTIONS)} (leave it out)")
    threads = parse_threads(threads)
    runtimes = parse_runtimes(runtimes)
    t0 = time.perf_counter()
    module = load_fb_checkpoint(Path(ckpt))  # refuses other kinds with a message
    load_s = time.perf_counter() - t0
    case = bench_case(module, Path(ckpt), dataset_dir, sim_id)
    sim_seconds = check_sim_seconds(case.scene, sim_seconds)
    with BedFile(case.file) as f:
        check_grid(module.norm, f)
        state = initial_state(f)
    try:
        recorded = solver_recorded(case.manifest, case.dataset_dir)
    except DataError:
        if reuse_dataset:
            raise
        recorded = None  # e.g. an imported dataset: no datagen costs, the measured runs stand alone
    return Plan(Path(ckpt), module, load_s, case, state, rollout_steps or module.norm.horizon_steps, threads,
                runtimes, repeats, solver_repeats, sim_seconds, recorded, reuse_dataset, Path(workdir), keep_runs, seed,
                options)


def measure(plan: Plan, clock: Clock = SYSTEM_CLOCK) -> dict[str, Any]:
    """Time DPMFoam (unless reusing the manifest's costs) and the surrogate; the results of fb_speed.json."""
    case, module, norm = plan.case, plan.module, plan.module.norm
    solvers = {"DPMFoam, dataset manifest": plan.recorded} if plan.recorded else {}
    if not plan.reuse_dataset:
        measured = solver_measured(case, plan.sim_seconds, plan.solver_repeats, plan.workdir, plan.keep_runs)
        solvers = {"DPMFoam, measured": measured, **solvers}
    surrogates = {surrogate_label(rt, t): surrogate_timing(module, case.velocity, plan.state, plan.steps,
                                                           plan.repeats, t, plan.seed, clock=clock,
                                                           options=plan.options, runtime=rt)
                  for rt in plan.runtimes for t in plan.threads}
    return {
        "scene": module.metadata["data_name"], "checkpoint": str(plan.ckpt.resolve()),
        "dataset": str(case.dataset_dir), "sim_id": case.record.sim_id, "inlet_velocity": case.velocity,
        "extrapolation": not norm.in_trained_range(case.velocity),
        "trained_velocity_range": [norm.velocity_lo, norm.velocity_hi], "packing_seed": case.seed,
        "n_particles": case.scene.n_particles, "cells": list(case.scene.cells), "dt": norm.dt,
        "unit": "seconds per simulated second",
        "solver": {label: t.as_dict() for label, t in solvers.items()},
        "surrogate": {label: s.as_dict() for label, s in surrogates.items()},
        "surrogate_parameters": sum(p.numel() for p in module.net.parameters()), "surrogate_load_s": plan.load_s,
        **plan.options.as_dict(STEP_COST_OPTIONS),
        "side_by_side": compare(solvers, surrogates), "target_speedup": TARGET_SPEEDUP,
    }


def main(argv: list[str]) -> int:
    p = command_parser(f"neuraldem.bench {NAME}", __doc__, summary=True)
    add_trajectory_options(p, ckpt_help="fluidized-bed checkpoint (<run>/checkpoints/last.ckpt)",
                           sim_help="trajectory id (default: the first test trajectory of its split)")
    p.add_argument("--repeats", type=int, default=3, help="timed rollouts per thread setting (median)")
    p.add_argument("--solver-repeats", type=int, default=3, help="fresh DPMFoam runs (median)")
    p.add_argument("--sim-seconds", type=float, default=DEFAULT_SIM_SECONDS,
                   help="stored seconds of each DPMFoam run, after the dataset's spin-up (a multiple of its "
                        "snapshot interval)")
    p.add_argument("--rollout-steps", type=int, default=None,
                   help="steps of each timed rollout (default: the model's training horizon)")
    p.add_argument("--threads", type=int, nargs="+", default=None,
                   help="thread counts of the surrogate (default: 1 and every usable core)")
    p.add_argument("--runtime", nargs="+", default=None,
                   help="what steps the surrogate's net: torch and/or onnx (default both, onnx where installed)")
    p.add_argument("--reuse-dataset", action="store_true",
                   help="run no DPMFoam: compare with the costs the manifest recorded (labelled in the output)")
    p.add_argument("--seed", type=int, default=0, help="seed of the rollout's particle re-sampling")
    add_arguments(p, STEP_COST_OPTIONS)
    p.add_argument("--workdir", type=Path, default=None, help=f"DPMFoam runs (default <data dir>/bench/{NAME})")
    p.add_argument("--keep-runs", action="store_true", help="keep the DPMFoam case folders")
    p.add_argument("--out", type=Path, default=None,
                   help=f"results JSON, or a folder for {NAME}.json (default results/fluidized_bed/speed/{NAME}.json); "
                        ".md and .png beside it")
    a = p.parse_args(argv)
    out = resolve_out(a.out, NAME)
    plan = prepare(a.ckpt, a.dataset, a.sim, a.repeats, a.solver_repeats, a.sim_seconds, a.rollout_steps,
                   a.threads, a.reuse_dataset, a.workdir or default_workdir(NAME), a.keep_runs, a.seed,
                   RolloutOptions.from_args(a), a.runtime)
    machine = machine_info()
    warning = warn_if_busy(machine)
    results = measure(plan)
    results["warning"] = warning
    path = write_results(NAME, results, command=command_line(NAME, argv), path=out, machine=machine)
    text = render_markdown(results, machine)
    path.with_suffix(".md").write_text(text)
    plots.fb_speed_figure(results, path.with_suffix(".png"))
    print(text)
    print(f"wrote {path}, {path.with_suffix('.md')} and {path.with_suffix('.png')}")
    return 0
