"""LIGGGHTS against the trained surrogate on the same hopper questions, side by side in one run.

`neuraldem bench hopper_speed ckpt=CKPT [dataset=DIR] [repeats=5] [solver_repeats=3]
[reuse_dataset=true] [reduced_queries=1000] [threads=1]` writes results/hopper/speed/hopper_speed.json and .md.

Question 1: occupancy, transport and residence at every initial particle position for every snapshot time.
Question 2: the same at a reduced set of query points. The solver answers both by simulating the hopper
(the same scene, parameters and seeds as the dataset's simulation) and computing the fields from the
particles; the surrogate by evaluating the model at each snapshot time. Ratios are of medians over repeats.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from neuraldem.bench.choices import default_workdir, pick_record
from neuraldem.bench.report import command_line, default_path, machine_info, warn_if_busy, write_results
from neuraldem.bench.timing import SYSTEM_CLOCK, Clock, Sample, Timing, side_by_side, time_call, torch_threads
from neuraldem.cli import add_trajectory_options, command_parser
from neuraldem.config import checks
from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.errors import DataError, SolverError
from neuraldem.paths import data_dir
from neuraldem.scenes.hopper.bench.solver import SOLVER_THREADS, dataset_scene, run_scene
from neuraldem.scenes.hopper.bench.surrogate import (
    Question,
    Surrogate,
    answer,
    full_question,
    load_surrogate,
    reduced_question,
    surrogate_dataset,
)
from neuraldem.scenes.hopper.dataset.fields import capped_exit_times, trajectory_fields_at
from neuraldem.scenes.hopper.dataset.store import HopperFile
from neuraldem.scenes.hopper.solver import STATUS_FAILED, HopperScene, HopperTrajectory

NAME = "hopper_speed"
# the surrogate's time grid: up to its horizon (every run's length, conservative) or the stored run's own snapshots
TIME_GRIDS = ("horizon", "solver")
RECORDED = "dataset manifest: CPU/wall seconds recorded when the dataset was generated, not re-run"


# ---- the solver's answer: simulate, then compute the fields from the particles

def solver_timing_measured(scene: HopperScene, rec: SimRecord, repeats: int, workdir: Path,
                           keep: bool = False) -> tuple[Timing, HopperTrajectory]:
    """Re-run the dataset's simulation `repeats` times (wall time, and CPU time of the LIGGGHTS process)."""
    samples, traj = [], None
    for r in range(checks.positive_int("solver_repeats", repeats)):
        result = run_scene(scene, rec.params, workdir / f"repeat_{r}", rec.index, keep=keep)
        if result.status == STATUS_FAILED or result.solver is None or result.trajectory is None:
            raise SolverError(f"LIGGGHTS run of {rec.sim_id} failed: {result.reason}")
        samples.append(Sample(result.solver.wall_s, result.solver.cpu_s))
        traj = result.trajectory
    assert traj is not None
    return Timing(samples, notes={"solver_threads": SOLVER_THREADS}), traj


def solver_timing_recorded(m: Manifest, dataset_dir: Path, rec: SimRecord) -> tuple[Timing, HopperTrajectory]:
    """The per-simulation costs the manifest recorded at datagen (every usable run), and `rec`'s stored
    trajectory for the post-processing step."""
    costs = [r.cost for r in m.usable() if "cpu_s" in r.cost and "wall_s" in r.cost]
    if not costs:
        raise DataError(f"{dataset_dir}/manifest.json records no cpu_s/wall_s cost for any simulation: drop "
                        "reuse_dataset=true to time LIGGGHTS here")
    with HopperFile(Path(dataset_dir) / str(rec.file)) as f:
        traj = f.load()
    timing = Timing([Sample(c["wall_s"], c["cpu_s"]) for c in costs], source=RECORDED,
                    notes={"solver_threads": SOLVER_THREADS, "dataset": str(dataset_dir),
                           "note": "wall times were recorded with datagen's workers running side by side"})
    return timing, traj


def dem_fields(traj: HopperTrajectory, q: Question, radius: float) -> Any:
    """The solver-side post-processing: fields at the question's points at every stored snapshot."""
    exits = capped_exit_times(traj.exit_times, float(traj.times[-1]))
    return trajectory_fields_at(q.points, traj.times, traj.positions, exits, radius)


# ---- side by side

def measure(surrogate: Surrogate, questions: dict[str, Question], solver_run: Timing, traj: HopperTrajectory,
            radius: float, repeats: int, threads: int, clock: Clock = SYSTEM_CLOCK) -> dict[str, Any]:
    """Time the surrogate and the solver's post-processing on every question (same clock, same threads)
    and put them side by side with the solver's simulation timing."""
    rows, details = [], {}
    with torch_threads(threads):
        for label, q in questions.items():
            post, _ = time_call(lambda q=q: dem_fields(traj, q, radius), repeats, warmup=0, clock=clock)
            model, _ = time_call(lambda q=q: answer(surrogate, q), repeats, warmup=1, clock=clock)
            rows.append(side_by_side([solver_run, post], model, label))
            details[label] = {"question": q.describe(), "solver_postprocess": post.as_dict(),
                              "surrogate": model.as_dict()}
    return {"side_by_side": rows, "details": details, "solver_simulation": solver_run.as_dict(),
            "threads": {"surrogate_torch_threads": threads, "solver_threads": SOLVER_THREADS,
                        "solver_postprocess": "numpy/scipy, one thread"}}


def render_markdown(results: dict[str, Any], machine: dict[str, Any]) -> str:
    source = results["solver_simulation"]["source"]
    threads = results["threads"]["surrogate_torch_threads"]
    full = results["details"]["all particle positions"]["question"]
    lines = [f"Scene {results['scene']}, simulation {results['sim_id']}; solver timing: {source}.",
             (f"Surrogate time grid: {results.get('time_grid', 'horizon')} ({full['n_times']} snapshot times up to "
              f"{full['horizon_s']:g} s); the stored LIGGGHTS run has {results['solver_trajectory']['n_snapshots']} "
              f"snapshots up to {results['solver_trajectory']['duration_s']:g} s."),
             (f"Machine: {machine.get('cpu_model')} ({machine.get('cpu_count')} cores); surrogate {threads} torch "
              f"thread(s), LIGGGHTS serial. Medians of {results['surrogate_repeats']} surrogate / "
              f"{results['solver_simulation']['repeats']} solver repeats."),
             "",
             ("| question | LIGGGHTS wall [s] | LIGGGHTS CPU [s] | surrogate wall [s] | surrogate CPU [s] | "
              "speed-up (wall) | speed-up (CPU) |"),
             "|---|---|---|---|---|---|---|"]
    for r in results["side_by_side"]:
        lines.append(f"| {r['question']} | {r['solver_wall_s']:.2f} | {r['solver_cpu_s']:.2f} | "
                     f"{r['surrogate_wall_s']:.4f} | {r['surrogate_cpu_s']:.4f} | {_x(r['speedup_wall'])} | "
                     f"{_x(r['speedup_cpu'])} |")
    return "\n".join(lines) + "\n"


def _x(v: float | None) -> str:
    return "n/a" if v is None else f"{v:,.0f}x"


def run(ckpt: Path, dataset_dir: Path | None, sim_id: str | None, repeats: int, solver_repeats: int,
        reuse_dataset: bool, reduced_queries: int, threads: int, workdir: Path, keep_runs: bool = False,
        time_grid: str = "horizon", clock: Clock = SYSTEM_CLOCK) -> dict[str, Any]:
    checks.positive_int("repeats", repeats)
    checks.positive_int("reduced_queries", reduced_queries)
    checks.one_of("time_grid", time_grid, TIME_GRIDS)
    surrogate = load_surrogate(ckpt)
    dataset_dir, m = surrogate_dataset(surrogate, dataset_dir, data_dir() / "datasets")
    scene, _ = dataset_scene(dataset_dir)
    rec = pick_record(m, surrogate.metadata["split"], sim_id)
    full = full_question(m, dataset_dir, rec, surrogate.predictor.norm)
    if time_grid == "solver":
        with HopperFile(Path(dataset_dir) / str(rec.file)) as f:
            full = Question(rec, f.times, full.points)
    questions = {"all particle positions": full,
                 f"{min(reduced_queries, len(full.points))} query points": reduced_question(full, reduced_queries)}
    if reuse_dataset:
        solver_run, traj = solver_timing_recorded(m, dataset_dir, rec)
    else:
        solver_run, traj = solver_timing_measured(scene, rec, solver_repeats, workdir, keep_runs)
    radius = float(surrogate.metadata["occupancy_radius_d"]) * scene.material.diameter
    results = measure(surrogate, questions, solver_run, traj, radius, repeats, threads, clock)
    results.update(scene=surrogate.metadata["data_name"], sim_id=rec.sim_id, params=rec.params, time_grid=time_grid,
                   checkpoint=str(Path(ckpt).resolve()), dataset=str(dataset_dir), surrogate_repeats=repeats,
                   surrogate_parameters=surrogate.parameters, surrogate_load_s=surrogate.load_s,
                   solver_trajectory={"n_snapshots": len(traj.times), "duration_s": float(traj.times[-1]),
                                      "n_particles": traj.n_particles})
    return results


def main(argv: list[str]) -> int:
    p = command_parser(f"neuraldem.bench {NAME}", __doc__, summary=True)
    add_trajectory_options(p, ckpt_help="hopper checkpoint (e.g. <run>/checkpoints/last.ckpt)",
                           sim_help="simulation id (default: the first test simulation)")
    p.add_argument("--repeats", type=int, default=5, help="timed surrogate/post-processing repeats (median)")
    p.add_argument("--solver-repeats", type=int, default=3, help="LIGGGHTS runs (median)")
    p.add_argument("--reuse-dataset", action="store_true",
                   help="take LIGGGHTS's cost from the manifest instead of re-running (labelled in the output)")
    p.add_argument("--reduced-queries", type=int, default=1000, help="points of the reduced question")
    p.add_argument("--threads", type=int, default=1, help="torch threads of the surrogate")
    p.add_argument("--time-grid", choices=TIME_GRIDS, default="horizon",
                   help="surrogate times: every snapshot up to the model's horizon (default; more than a run "
                        "stores), or exactly the stored run's snapshot times")
    p.add_argument("--workdir", type=Path, default=None, help=f"solver runs (default <data dir>/bench/{NAME})")
    p.add_argument("--keep-runs", action="store_true", help="keep the LIGGGHTS run folders")
    p.add_argument("--out", type=Path, default=None, help=f"default results/hopper/speed/{NAME}.json (+ .md beside it)")
    a = p.parse_args(argv)
    checks.positive_int("threads", a.threads)
    checks.positive_int("solver_repeats", a.solver_repeats)
    machine = machine_info()
    warning = warn_if_busy(machine)
    results = run(a.ckpt, a.dataset, a.sim, a.repeats, a.solver_repeats, a.reuse_dataset, a.reduced_queries,
                  a.threads, a.workdir or default_workdir(NAME), a.keep_runs, a.time_grid)
    results["warning"] = warning
    out = a.out or default_path(NAME)
    path = write_results(NAME, results, command=command_line(NAME, argv), path=out, machine=machine)
    text = render_markdown(results, machine)
    path.with_suffix(".md").write_text(text)
    print(text)
    print(f"wrote {path} and {path.with_suffix('.md')}")
    return 0
