"""How the cost grows: LIGGGHTS with the particle count, the surrogate with query points and latent tokens.

`neuraldem bench hopper_scaling [dataset=DIR] [particles=[2000,5000,10000,20000,50000]]
[steps=1000] [full_up_to=5000] [ckpt=CKPT | model=hopper_base] [queries=[...]] [tokens=[...]]`
writes results/hopper/speed/hopper_scaling.json and hopper_scaling.png (log-log).

LIGGGHTS: the dataset's hopper scaled to N particles (same shape); each N is filled, settled and drained for
2 x `steps=` timesteps only (the first `steps=` start the flow). Measured: settle time, particle-steps per
second of the second chunk (LIGGGHTS's own loop clock) and the process's wall/CPU time. Extrapolated: a full
run = measured settle + a full drain's particle-steps / the measured rate, where a full drain's duration and
mean fill come from the dataset's stored runs. Counts up to `full_up_to=` are also run in full, which checks
the extrapolation.
Surrogate: one full trajectory (every snapshot time) at Q uniform query points; and at a fixed Q for
untrained copies of the net with other latent token counts (the cost does not depend on the weights).
"""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.bench import plots
from neuraldem.bench.choices import default_workdir
from neuraldem.bench.report import command_line, default_path, machine_info, read_results, warn_if_busy, write_results
from neuraldem.bench.timing import SYSTEM_CLOCK, Clock, time_call, torch_threads
from neuraldem.cli import command_parser, parse_assignments
from neuraldem.config import checks
from neuraldem.errors import ConfigError, DataError, SolverError
from neuraldem.paths import data_dir
from neuraldem.scenes.hopper.bench.solver import (
    SOLVER_THREADS,
    DrainProfile,
    dataset_scene,
    drain_profile_of_dataset,
    extrapolated_full_run,
    phase_cost,
    run_scene,
    scaled_scene,
    shortened_scene,
)
from neuraldem.scenes.hopper.bench.surrogate import (
    Surrogate,
    answer,
    load_surrogate,
    net_config_of,
    synthetic_question,
    untrained_surrogate,
)
from neuraldem.scenes.hopper.solver import STATUS_FAILED, HopperRunResult, HopperScene
from neuraldem.scenes.hopper.surrogate.predictors import time_grid
from neuraldem.sim.liggghts import find_liggghts

NAME = "hopper_scaling"
DEFAULT_PARTICLES = (2000, 5000, 10000, 20000, 50000)
DEFAULT_QUERIES = (1000, 2000, 5000, 10000, 20000, 50000)
DEFAULT_TOKENS = (8, 16, 32, 64, 128)
DEFAULT_PARAMS = {"alpha": 30.0, "mu_s": 0.5, "mu_r": 0.1}
CONDITIONING = ["t", "alpha", "mu_s", "mu_r"]


# ---- LIGGGHTS

def _require_ran(result: HopperRunResult, what: str) -> HopperRunResult:
    if result.status == STATUS_FAILED or result.solver is None:
        raise SolverError(f"LIGGGHTS {what} failed: {result.reason}")
    return result


def solver_point(base: HopperScene, n: int, steps: int, params: dict[str, float], profile: DrainProfile,
                 repeats: int, full: bool, workdir: Path) -> dict[str, Any]:
    """One particle count: the shortened run (`repeats` times, medians) and, if `full`, one full run."""
    scene = scaled_scene(base, n)
    short = shortened_scene(scene, steps)
    reps = []
    for r in range(checks.positive_int("solver_repeats", repeats)):
        result = _require_ran(run_scene(short, params, workdir / f"n{n}_short_{r}", 0),
                              f"shortened run, {n} particles")
        cost = phase_cost(result.solver.log, n)
        reps.append({"process_wall_s": result.solver.wall_s, "process_cpu_s": result.solver.cpu_s,
                     **cost.as_dict(), **extrapolated_full_run(n, cost, profile, scene.material.dt)})
    point: dict[str, Any] = {
        "n_particles": n, "hopper_diameter": scene.hopper_diameter, "outlet_diameter": scene.outlet_diameter,
        "settle_time": scene.settle_time, "steps_per_drain_chunk": steps, "repeats": reps,
        "measured": {k: statistics.median(r[k] for r in reps) for k in
                     ("process_wall_s", "process_cpu_s", "settle_s", "drain_particle_steps_per_s",
                      "settle_particle_steps_per_s")},
        "extrapolated": {"full_run_s": statistics.median(r["full_run_s_extrapolated"] for r in reps),
                         "drain_s": statistics.median(r["drain_s_extrapolated"] for r in reps)},
    }
    if full:
        point["full_run_measured"] = full_run_check(scene, n, params, point, workdir / f"n{n}_full")
    return point


def full_run_check(scene: HopperScene, n: int, params: dict[str, float], point: dict[str, Any],
                   workdir: Path) -> dict[str, Any]:
    """A full run of N particles, and the extrapolation redone with this run's own drain duration and fill,
    so that the difference left is the error of extrapolating with the measured rate."""
    result = _require_ran(run_scene(scene, params, workdir, 0), f"full run, {n} particles")
    traj = result.trajectory
    assert traj is not None and result.solver is not None
    times = traj.times
    inside = np.isfinite(traj.positions[..., 0]).mean(axis=1)
    own = DrainProfile(float(times[-1]), float(np.trapezoid(inside, times) / times[-1]), "this full run")
    rate = point["measured"]["drain_particle_steps_per_s"]
    cost = phase_cost(result.solver.log, n)
    loop_s = cost.settle.seconds + cost.drain_seconds
    own_estimate = point["measured"]["settle_s"] + own.particle_steps(n, scene.material.dt) / rate
    return {"process_wall_s": result.solver.wall_s, "process_cpu_s": result.solver.cpu_s, "loop_s": loop_s,
            "drain_profile": own.as_dict(), "extrapolated_with_own_profile_s": own_estimate,
            "extrapolation_error_pct": 100.0 * (own_estimate / loop_s - 1.0)}


def solver_scaling(dataset_dir: Path, counts: list[int], steps: int, full_up_to: int, params: dict[str, float],
                   profile: DrainProfile | None, repeats: int, workdir: Path) -> dict[str, Any]:
    base, _ = dataset_scene(dataset_dir)
    profile = profile or drain_profile_of_dataset(dataset_dir)
    points = []
    for n in counts:  # a count whose run fails is recorded and the sweep goes on (the failure is a result)
        try:
            points.append(solver_point(base, n, steps, params, profile, repeats, n <= full_up_to, workdir))
        except SolverError as err:
            points.append({"n_particles": n, "failed": str(err)})
    return {"dataset": str(dataset_dir), "base_particles": base.n_particles, "params": params,
            "drain_profile": profile.as_dict(), "threads": SOLVER_THREADS, "points": points,
            "clock": "LIGGGHTS loop time (wall clock of its run commands); process wall/CPU from the OS"}


# ---- surrogate

def surrogate_scaling(surrogate: Surrogate, net_cfg: dict | str, queries: list[int], tokens: list[int],
                      token_queries: int, n_times: int, repeats: int, threads: int,
                      clock: Clock = SYSTEM_CLOCK) -> dict[str, Any]:
    """Seconds per full trajectory (`n_times` model calls) vs query points, and vs latent tokens."""
    checks.positive_int("n_times", n_times)
    by_queries, by_tokens = [], []
    with torch_threads(threads):
        for n in queries:
            q = synthetic_question(surrogate, checks.positive_int("queries", n), n_times)
            t, _ = time_call(lambda q=q: answer(surrogate, q), repeats, warmup=1, clock=clock)
            by_queries.append({"n_queries": n, **t.as_dict()})
        for k in tokens:
            s = untrained_surrogate(net_cfg, surrogate.predictor.conditioning,
                                    n_latent_tokens=checks.positive_int("tokens", k))
            q = synthetic_question(s, token_queries, n_times)
            t, _ = time_call(lambda s=s, q=q: answer(s, q), repeats, warmup=1, clock=clock)
            by_tokens.append({"n_latent_tokens": k, "n_queries": token_queries, "parameters": s.parameters,
                              **t.as_dict()})
    return {"n_times": n_times, "threads": threads, "parameters": surrogate.parameters,
            "weights": "trained checkpoint" if surrogate.checkpoint else "untrained (cost does not depend on weights)",
            "by_queries": by_queries, "by_tokens": by_tokens}


def main(argv: list[str]) -> int:
    p = command_parser(f"neuraldem.bench {NAME}", __doc__, summary=True)
    p.add_argument("--dataset", type=Path, default=None,
                   help="reference dataset: its scene is scaled, its runs give the full drain "
                        "(default: the dataset of ckpt=, else <data dir>/datasets/hopper_small)")
    p.add_argument("--particles", type=int, nargs="+", default=list(DEFAULT_PARTICLES))
    p.add_argument("--steps", type=int, default=1000,
                   help="timesteps per drain chunk after settling (2 chunks; the second one is measured)")
    p.add_argument("--full-up-to", type=int, default=5000, help="also run counts up to this in full (0: none)")
    p.add_argument("--solver-repeats", type=int, default=1)
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help=f"alpha, mu_s, mu_r of the runs (default {DEFAULT_PARAMS})")
    p.add_argument("--drain-time", type=float, default=None, help="full drain [s] (default: from the dataset)")
    p.add_argument("--remaining-fraction", type=float, default=None,
                   help="mean share of particles inside during the drain (default: from the dataset)")
    p.add_argument("--skip-solver", action="store_true", help="surrogate part only")
    p.add_argument("--reuse-solver", type=Path, default=None,
                   help="take the LIGGGHTS part from an earlier hopper_scaling.json instead of running")
    p.add_argument("--ckpt", type=Path, default=None, help="hopper checkpoint (its net and horizon)")
    p.add_argument("--model", default="hopper_base", help="conf/model/ name, untrained, when no ckpt=")
    p.add_argument("--queries", type=int, nargs="+", default=list(DEFAULT_QUERIES))
    p.add_argument("--tokens", type=int, nargs="+", default=list(DEFAULT_TOKENS))
    p.add_argument("--token-queries", type=int, default=5000, help="query points of the token sweep")
    p.add_argument("--n-times", type=int, default=None,
                   help="snapshot times per trajectory (default: the checkpoint's horizon / the dataset's "
                        "snapshot interval, else 81)")
    p.add_argument("--repeats", type=int, default=3, help="timed surrogate repeats (median)")
    p.add_argument("--threads", type=int, default=1, help="torch threads of the surrogate")
    p.add_argument("--workdir", type=Path, default=None, help=f"solver runs (default <data dir>/bench/{NAME})")
    p.add_argument("--out", type=Path, default=None,
                   help=f"default results/hopper/speed/{NAME}.json (+ .png beside it)")
    a = p.parse_args(argv)
    params = {**DEFAULT_PARAMS, **parse_assignments(a.param, "param", "alpha=30")}
    for key in params:
        checks.one_of("param", key, DEFAULT_PARAMS)
    for key in ("steps", "token_queries", "threads", "repeats", "solver_repeats"):
        checks.positive_int(key, getattr(a, key))
    checks.positive_int("full_up_to", a.full_up_to, allow_zero=True)
    for key in ("particles", "queries", "tokens"):
        for v in getattr(a, key):
            checks.positive_int(key, v)
    if a.n_times is not None:
        checks.positive_int("n_times", a.n_times)
    profile = None
    if (a.drain_time is None) != (a.remaining_fraction is None):
        raise ConfigError("drain_time= and remaining_fraction= go together (both describe the full drain): "
                          "give both, or neither to take them from the dataset's stored runs")
    if a.drain_time is not None:
        profile = DrainProfile(checks.positive("drain_time", a.drain_time),
                               checks.fraction("remaining_fraction", a.remaining_fraction), "command line")
    # everything that can fail is checked before the first measurement
    reused = reused_solver_part(a.reuse_solver) if a.reuse_solver is not None else None
    if a.ckpt is not None:
        surrogate, net_cfg = load_surrogate(a.ckpt), net_config_of(a.ckpt)
        dataset = a.dataset or data_dir() / "datasets" / surrogate.metadata["data_name"]
    else:
        surrogate, net_cfg = untrained_surrogate(a.model, CONDITIONING), a.model
        dataset = a.dataset or data_dir() / "datasets" / "hopper_small"
    run_solver = reused is None and not a.skip_solver
    if run_solver or a.ckpt is not None:
        base, _ = dataset_scene(dataset)
    if run_solver:
        find_liggghts()
    n_times = a.n_times or (len(time_grid(surrogate.predictor.norm.horizon, base.snapshot_interval))
                            if a.ckpt is not None else 81)
    machine = machine_info()
    warning = warn_if_busy(machine)
    results: dict[str, Any] = {"warning": warning, "surrogate": surrogate_scaling(
        surrogate, net_cfg, a.queries, a.tokens, a.token_queries, n_times, a.repeats, a.threads)}
    if reused is not None:
        results["solver"] = reused
    elif run_solver:
        results["solver"] = solver_scaling(dataset, a.particles, a.steps, a.full_up_to, params, profile,
                                           a.solver_repeats, a.workdir or default_workdir(NAME))
    path = write_results(NAME, results, command=command_line(NAME, argv), path=a.out or default_path(NAME),
                         machine=machine)
    figure = plots.scaling_figure(results, path.with_suffix(".png"))
    print(summary(results))
    print(f"wrote {path} and {figure}")
    return 0


def reused_solver_part(path: Path) -> dict[str, Any]:
    """The LIGGGHTS part of an earlier hopper_scaling.json (labelled as reused)."""
    solver = read_results(path, NAME)["results"].get("solver")
    if solver is None:
        raise DataError(f"{path} has no LIGGGHTS part (it was run with skip_solver=true): run "
                        f"`neuraldem bench {NAME}` without skip_solver=true once")
    return {**solver, "reused_from": str(path)}


def summary(results: dict[str, Any]) -> str:
    lines = []
    if "solver" in results:
        lines.append("LIGGGHTS (settle + N steps measured; full run extrapolated):")
        for pt in results["solver"]["points"]:
            if "failed" in pt:
                lines.append(f"  {pt['n_particles']:>7} particles: {pt['failed']}")
                continue
            m, e = pt["measured"], pt["extrapolated"]
            line = (f"  {pt['n_particles']:>7} particles: {m['drain_particle_steps_per_s']:.3g} particle-steps/s, "
                    f"full run ~{e['full_run_s']:.1f} s (extrapolated)")
            if "full_run_measured" in pt:
                f = pt["full_run_measured"]
                line += f", measured {f['loop_s']:.1f} s ({f['extrapolation_error_pct']:+.0f} % with its own drain)"
            lines.append(line)
    s = results["surrogate"]
    lines.append(f"surrogate ({s['n_times']} times per trajectory, {s['threads']} thread(s)):")
    lines += [f"  {r['n_queries']:>7} query points: {r['median_wall_s']:.3f} s" for r in s["by_queries"]]
    lines += [f"  {r['n_latent_tokens']:>7} latent tokens: {r['median_wall_s']:.3f} s" for r in s["by_tokens"]]
    return "\n".join(lines)
