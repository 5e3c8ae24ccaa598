"""The speed-accuracy chart: time to answer one trajectory against the error of what a practitioner asks.

`neuraldem bench speed_accuracy runs=[DIR,...] [solver_variants=[same:1,fewer:0.5,...]]
[solver_sims=3] [reuse_solver=FILE] [skip_solver=true]` writes results/speed_accuracy/speed_accuracy.json, .png, .md.

Points: every evaluated surrogate run under the folders (errors from its evaluation/metrics.json, time to
answer measured here), LIGGGHTS at cheaper settings scored against the dataset's reference runs of the
same parameters (`scenes.hopper.bench.solver_variants`), and with `gns_ckpt=` the particle-based GNS baseline rolled
out over whole test trajectories (`gns.bench.points`). One panel per quantity (drainage time, residual, outflow); the
Pareto front of each panel is what users should choose from. With `cv=FILE.json` (the cross-validated table
of `neuraldem report hopper-cv`) the chart also holds the constant and Gaussian-process baselines and the field
model at their cross-validated errors, and LIGGGHTS rerun with another packing seed, drawn as the floor line.
With `query_budget=FILE.json` (`neuraldem bench query_budget`) the field model's errors over its query budget
(shares of the query points and time strides, on the released model's validation runs) are drawn as a curve:
what each decimal of accuracy costs in answer time.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from neuraldem.bench import plots
from neuraldem.bench.choices import default_workdir
from neuraldem.bench.pareto import pareto_front
from neuraldem.bench.report import command_line, default_path, machine_info, read_results, warn_if_busy, write_results
from neuraldem.bench.timing import SYSTEM_CLOCK, Clock
from neuraldem.cli import command_parser
from neuraldem.config import checks
from neuraldem.errors import ConfigError, DataError
from neuraldem.gns.bench.points import gns_point, require_hopper_gns
from neuraldem.paths import data_dir
from neuraldem.scenes.hopper.analysis.cv import ROWS
from neuraldem.scenes.hopper.bench.runs import HOPPER_ERRORS, EvaluatedRun, collect_runs, time_to_answer
from neuraldem.scenes.hopper.bench.solver import dataset_scene, split_records
from neuraldem.scenes.hopper.bench.solver_variants import DEFAULT_VARIANTS, SolverVariant, score_variant
from neuraldem.sim.liggghts import find_liggghts

NAME = "speed_accuracy"


def read_cv(path: Path) -> dict[str, Any]:
    if not Path(path).is_file():
        raise DataError(f"cv={path} does not exist: make it with neuraldem report hopper-cv dataset=DIR "
                        "[grids=[GRID,...]] out=FILE.md (pass FILE.json)")
    try:
        cv = json.loads(Path(path).read_text())
    except json.JSONDecodeError as err:
        raise DataError(f"cv={path} is not valid JSON ({err}): write it again with "
                        "neuraldem report hopper-cv") from None
    if "summary" not in cv or "folds" not in cv:
        raise DataError(f"cv={path} is not a cross-validation result of neuraldem report hopper-cv (no summary)")
    return cv


def runs_of_one_scene(runs: list[EvaluatedRun], scene: str | None) -> list[EvaluatedRun]:
    """A chart compares answers to the same questions: runs of one dataset (`scene` picks it if several)."""
    names = sorted({r.data_name for r in runs})
    if scene is not None:
        picked = [r for r in runs if r.data_name == scene]
        if not picked:
            raise ConfigError(f"scene={scene!r}: no evaluated run of that dataset; the runs are of {names}")
        return picked
    if len(names) > 1:
        raise ConfigError(f"the runs are of several datasets {names}: pick one with scene=NAME")
    return runs


def surrogate_points(runs: list[EvaluatedRun], repeats: int, threads: int, dataset: Path | None,
                     clock: Clock = SYSTEM_CLOCK) -> list[dict[str, Any]]:
    points = []
    for run in runs:
        run.timing = time_to_answer(run, repeats, threads, dataset, clock).as_dict()
        points.append(run.as_point())
    return points


def solver_points(dataset_dir: Path, variants: list[SolverVariant], n_sims: int, split: str,
                  workdir: Path) -> list[dict[str, Any]]:
    """Each variant run for the parameters of the first `n_sims` test simulations of `split`."""
    base, m = dataset_scene(dataset_dir)
    records = split_records(m, split)[:checks.positive_int("solver_sims", n_sims)]
    cache: dict[str, dict[str, float]] = {}
    return [score_variant(v, base, records, dataset_dir, workdir, reference_cache=cache) for v in variants]


def reference_time(dataset_dir: Path, solver: list[dict[str, Any]]) -> dict[str, Any]:
    """LIGGGHTS at the reference settings: re-run here (variant same:1) if present, else the CPU seconds the
    manifest recorded at datagen for the same simulations."""
    for p in solver:
        if p.get("variant") == "same:1" and p.get("time_to_answer_s") is not None:
            return {"time_to_answer_s": p["time_to_answer_s"], "source": "measured (variant same:1)"}
    _, m = dataset_scene(dataset_dir)
    sims = {s["sim_id"] for p in solver for s in p.get("simulations", [])} or {r.sim_id for r in m.usable()}
    cpu = sorted(m.record(s).cost["cpu_s"] for s in sims if "cpu_s" in m.record(s).cost)
    if not cpu:
        return {}
    return {"time_to_answer_s": cpu[len(cpu) // 2], "source": "dataset manifest: CPU s recorded at datagen"}


CV_METHODS = {"constant": "constant (training mean)", "gp": "Gaussian process", "field model": "field model (CV)"}


def cv_points(cv: dict[str, Any], split: str, row: str, scene: str) -> tuple[list[dict[str, Any]], dict[str, float]]:
    """Chart points of a cross-validated table (`neuraldem.scenes.hopper.analysis.cv`): every method's mean error over
    the
    folds at its measured time per answer, and the LIGGGHTS seed floor (its errors per quantity)."""
    summary = cv.get("summary", {}).get(split, {}).get(row)
    if not summary:
        raise DataError(f"the cross-validation file has no {split}/{row} rows (has "
                        f"{ {k: sorted(v) for k, v in cv.get('summary', {}).items()} }): "
                        "pick them with cv_split= / cv_row=")
    points = []
    for method, s in summary.items():
        kind = CV_METHODS.get(method) or (CV_METHODS["field model"] if method.startswith("field model") else method)
        points.append({"method": kind, "label": f"{method}, {s['n_folds']}-fold CV",
                       "data_name": scene, "split": split, "conditioning": ROWS[row],
                       "errors": {k: s[k]["mean"] for k in HOPPER_ERRORS if k in s},
                       "error_std": {k: s[k]["std"] for k in HOPPER_ERRORS if k in s},
                       "size": {"parameters": s.get("n_parameters")},
                       "time_to_answer_s": s["answer_s"]["mean"], "source": "cross-validation"})
    floor = cv.get("seed_floor") or {}
    if floor:
        points.append({"method": "LIGGGHTS, another packing seed",
                       "label": f"{floor['n_sets']} sets x {floor['n_seeds']} seeds",
                       "errors": {k: floor[k]["mean"] for k in HOPPER_ERRORS if k in floor},
                       "time_to_answer_s": floor["answer_s"]["mean"], "source": "bench seed_floor"})
    return points, {k: floor[k]["mean"] for k in HOPPER_ERRORS if k in floor}


def budget_curve(path: Path) -> dict[str, Any]:
    """The field model's accuracy against answer time over its query budget (one time stride: the chosen one),
    as a curve of the chart: a `neuraldem bench query_budget` results file."""
    r = read_results(path, "query_budget")["results"]
    stride = r["chosen"]["time_stride"]
    rows = sorted((b for b in r["budgets"] if b["time_stride"] == stride), key=lambda b: b["answer_s"])
    return {"label": f"field model {r['model']}, share of query points at every {stride}th time "
                     f"({len(r['runs'])} validation runs)",
            "points": [{"query_points": b["query_points"], "time_to_answer_s": b["answer_s"],
                        "errors": {k: b["errors"][k] for k in HOPPER_ERRORS if k in b["errors"]}} for b in rows],
            "chosen": r["chosen"], "source": str(path)}


def chart(points: list[dict[str, Any]]) -> dict[str, list[int]]:
    """Pareto front (indices into `points`) per quantity, over the points with a time and that error."""
    fronts = {}
    for key in HOPPER_ERRORS:
        xy = [(_num(p.get("time_to_answer_s")), _num(p.get("errors", {}).get(key))) for p in points]
        fronts[key] = pareto_front(xy)
    return fronts


def _num(v: Any) -> float:
    return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else float("nan")


def render_markdown(results: dict[str, Any]) -> str:
    keys = list(HOPPER_ERRORS)
    on_front = {k: set(results["pareto_front"][k]) for k in keys}
    lines = ["| method | point | time to answer [s] | " + " | ".join(HOPPER_ERRORS[k] for k in keys) + " |",
             "|---|---|---|" + "---|" * len(keys)]
    order = sorted(range(len(results["points"])),
                   key=lambda i: _num(results["points"][i].get("time_to_answer_s")))
    for i in order:
        p = results["points"][i]
        cells = []
        for k in keys:
            v = _num(p.get("errors", {}).get(k))
            cells.append("failed" if math.isnan(v) else f"{v:.2f}{' *' if i in on_front[k] else ''}")
        t = _num(p.get("time_to_answer_s"))
        lines.append(f"| {p['method']} | {p['label']} | {'-' if math.isnan(t) else f'{t:.3g}'} | "
                     + " | ".join(cells) + " |")
    ref = results.get("reference") or {}
    lines += ["", "`*` = on the Pareto front of that quantity (no point is both faster and more accurate)."]
    if ref:
        lines.append(f"LIGGGHTS reference: {ref['time_to_answer_s']:.3g} s per trajectory ({ref['source']}).")
    for curve in results.get("curves", []):
        lines += ["", f"Curve: {curve['label']} ({curve['source']}):", "",
                  "| query points (share) | time to answer [s] | " + " | ".join(HOPPER_ERRORS[k] for k in keys) + " |",
                  "|---|---|" + "---|" * len(keys)]
        for c in curve["points"]:
            chosen = " (chosen)" if c["query_points"] == curve["chosen"]["query_points"] else ""
            lines.append(f"| {c['query_points']:g}{chosen} | {c['time_to_answer_s']:.3g} | "
                         + " | ".join(f"{_num(c['errors'].get(k)):.2f}" for k in keys) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    p = command_parser(f"neuraldem.bench {NAME}", __doc__, summary=True)
    p.add_argument("--runs", type=Path, nargs="+", default=[], help="folders holding evaluated training runs")
    p.add_argument("--cv", type=Path, default=None,
                   help="a cross-validated table (neuraldem report hopper-cv ... out=X.md: pass X.json): "
                        "constant, Gaussian process and field model points, and the LIGGGHTS seed floor")
    p.add_argument("--cv-split", default="random", choices=["random", "band"])
    p.add_argument("--cv-row", default="micro", choices=["micro", "macro"])
    p.add_argument("--scene", default=None, help="dataset name, when the runs are of several")
    p.add_argument("--dataset", type=Path, default=None, help="dataset dir (default: the one the runs recorded)")
    p.add_argument("--skip-unevaluated", action="store_true", help="leave out runs without evaluation/metrics.json")
    p.add_argument("--repeats", type=int, default=3, help="timed surrogate answers per run (median)")
    p.add_argument("--threads", type=int, default=1, help="torch threads of the surrogate")
    p.add_argument("--solver-variants", nargs="+", default=list(DEFAULT_VARIANTS), metavar="KIND:FACTOR",
                   help="cheaper LIGGGHTS settings (see neuraldem.scenes.hopper.bench.solver_variants)")
    p.add_argument("--solver-sims", type=int, default=3, help="parameter sets each variant is run for")
    p.add_argument("--reuse-solver", type=Path, default=None,
                   help="take the LIGGGHTS points from an earlier speed_accuracy.json instead of running")
    p.add_argument("--skip-solver", action="store_true", help="surrogate points only")
    p.add_argument("--gns-ckpt", type=Path, nargs="+", default=[],
                   help="GNS checkpoints of the same scene (experiment=gns_hopper): rolled out as chart points")
    p.add_argument("--gns-sims", type=int, default=3, help="test simulations each GNS is rolled out on")
    p.add_argument("--query-budget", type=Path, default=None,
                   help="a query_budget.json (neuraldem bench query_budget): the field model's errors over its "
                        "query budget, drawn as a curve")
    p.add_argument("--workdir", type=Path, default=None, help=f"solver runs (default <data dir>/bench/{NAME})")
    p.add_argument("--out", type=Path, default=None, help=f"default results/speed_accuracy/{NAME}.json (+ .png, .md)")
    a = p.parse_args(argv)
    checks.positive_int("repeats", a.repeats)
    checks.positive_int("threads", a.threads)
    variants = [SolverVariant.parse(s) for s in a.solver_variants]
    if not a.runs and a.cv is None:
        raise ConfigError("nothing to chart: pass runs=[FOLDER,...] (evaluated training runs) and/or cv=FILE.json")
    cv = read_cv(a.cv) if a.cv is not None else None
    curves = [budget_curve(a.query_budget)] if a.query_budget is not None else []
    runs, notes = collect_runs(a.runs, a.skip_unevaluated) if a.runs else ([], [])
    runs = runs_of_one_scene(runs, a.scene) if runs else []
    dataset = a.dataset or next((r.dataset for r in runs if (r.dataset / "manifest.json").is_file()),
                                Path(cv["dataset"]) if cv else data_dir() / "datasets" / runs[0].data_name)
    scene = runs[0].data_name if runs else dataset.name
    split = runs[0].split if runs else a.cv_split
    # everything that can fail is checked before the first measurement
    solver: list[dict[str, Any]] = []
    reference: dict[str, Any] = {}
    run_solver = a.reuse_solver is None and not a.skip_solver
    if a.reuse_solver is not None:
        old = read_results(a.reuse_solver, NAME)["results"]
        if old.get("scene") != scene:
            raise DataError(f"reuse_solver={a.reuse_solver} holds LIGGGHTS points of scene {old.get('scene')!r}, "
                            f"the runs are of {scene!r}: pass results of the same scene")
        solver = [p for p in old["points"] if p["method"] == "liggghts"]
        reference = old.get("reference") or {}
        notes.append(f"LIGGGHTS points taken from {a.reuse_solver} (not re-run)")
    if run_solver:
        checks.positive_int("solver_sims", a.solver_sims)
        base, _ = dataset_scene(dataset)
        for v in variants:
            v.apply(base)
        find_liggghts()
    checks.positive_int("gns_sims", a.gns_sims)
    for ckpt in a.gns_ckpt:
        require_hopper_gns(ckpt)
    machine = machine_info()
    warning = warn_if_busy(machine)
    points = surrogate_points(runs, a.repeats, a.threads, a.dataset)
    floor: dict[str, float] = {}
    if cv is not None:
        cv_pts, floor = cv_points(cv, a.cv_split, a.cv_row, scene)
        points += cv_pts
        notes.append(f"constant / Gaussian process / field model (CV) points: {a.cv_split} folds, {a.cv_row} "
                     f"conditioning, from {a.cv}; their times are the measured time per answer of one run")
    points += [gns_point(c, a.gns_sims, a.dataset, a.threads) for c in a.gns_ckpt]
    if run_solver:
        solver = solver_points(dataset, variants, a.solver_sims, split, a.workdir or default_workdir(NAME))
        reference = reference_time(dataset, solver)
    points += solver
    results = {"scene": scene, "dataset": str(dataset), "quantities": HOPPER_ERRORS,
               "points": points, "pareto_front": chart(points), "reference": reference, "floor": floor,
               "curves": curves,
               "threads": {"surrogate_torch_threads": a.threads, "solver_threads": 1}, "notes": notes,
               "warning": warning}
    path = write_results(NAME, results, command=command_line(NAME, argv), path=a.out or default_path(NAME),
                         machine=machine)
    figure = plots.speed_accuracy_figure(results, path.with_suffix(".png"))
    text = render_markdown(results)
    path.with_suffix(".md").write_text(text)
    print(text)
    print(f"wrote {path}, {figure} and {path.with_suffix('.md')}")
    return 0
