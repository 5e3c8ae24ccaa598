"""Right-sizing: the smallest model within 10 % of the best accuracy, for each scene, with its speed.

`neuraldem bench right_sizing (runs=[DIR,...] | from_file=results/speed_accuracy/speed_accuracy.json)
[metric=drainage_t95_pct_of_mean|drainage_mae_pct_of_mean|residual_mae_pp|outflow_rel_err_pct|all]
[tolerance=0.10]` writes results/speed_accuracy/right_sizing.json and .md. Candidates are the field models and, from a
speed_accuracy.json made with `cv=FILE`, the scalar baselines (constant, Gaussian process).

Runs are compared only with runs that answer the same task: the same dataset, split and conditioning. Runs
of one task and one size (e.g. seeds) are one candidate: their errors averaged, their range kept, so one lucky
run does not decide the size.
"Within 10 %" means error <= 1.10 x the best error of the group. Among those, the smallest is the one with
the fewest parameters, then the fewest latent tokens, then the fewest training query points, then the
fastest answer: a bigger model is worth its cost only where it is measurably more accurate.
"""

from __future__ import annotations

import json
import math
import statistics
from pathlib import Path
from typing import Any

from neuraldem.bench.report import command_line, default_path, machine_info, read_results, write_results
from neuraldem.bench.speed_accuracy import surrogate_points
from neuraldem.cli import command_parser
from neuraldem.config import checks
from neuraldem.errors import DataError
from neuraldem.scenes.hopper.bench.runs import HOPPER_ERRORS, collect_runs

NAME = "right_sizing"
# what may answer a practitioner's question: field models (timed or cross-validated) and the scalar baselines
# (a Gaussian process on the scene scalars is the smallest model where the question is a few numbers)
CANDIDATE_METHODS = ("surrogate", "field model (CV)", "Gaussian process", "constant (training mean)")


def _value(v: Any) -> float:
    return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else math.inf


def size_key(row: dict[str, Any]) -> tuple[float, ...]:
    """Smaller first: parameters, latent tokens, training query points, then time to answer (unknown = last)."""
    size = row.get("size", {})
    return (_value(size.get("parameters")), _value(size.get("n_latent_tokens")),
            _value(size.get("train_queries")), _value(row.get("time_to_answer_s")))


def task_of(row: dict[str, Any]) -> tuple[str, str, tuple[str, ...]]:
    return (str(row.get("data_name")), str(row.get("split")), tuple(row.get("conditioning", [])))


def merge_repeats(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows of the same task and size (repeats, e.g. seeds) as one row: errors averaged (NaN unless every
    repeat has one), their [min, max] in `error_ranges`, the median time to answer, the labels joined."""
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for row in rows:
        key = (task_of(row), row.get("method"), json.dumps(row.get("size", {}), sort_keys=True, default=str))
        groups.setdefault(key, []).append(row)
    merged = []
    for group in groups.values():
        if len(group) == 1:
            merged.append(group[0])
            continue
        errors, ranges = {}, {}
        for k in sorted(set().union(*(r.get("errors", {}) for r in group))):
            values = [_value(r.get("errors", {}).get(k)) for r in group]
            ok = all(math.isfinite(v) for v in values)
            errors[k] = statistics.fmean(values) if ok else math.nan
            ranges[k] = [min(values), max(values)] if ok else None
        times = [_value(r.get("time_to_answer_s")) for r in group]
        labels = [r["label"] for r in group]
        merged.append({**group[0], "label": f"{' + '.join(labels)} (mean of {len(group)})", "errors": errors,
                       "error_ranges": ranges, "repeats": labels,
                       "time_to_answer_s": statistics.median(times) if all(map(math.isfinite, times)) else None,
                       "run_dir": [r.get("run_dir") for r in group]})
    return merged


def right_size(rows: list[dict[str, Any]], metric: str, tolerance: float = 0.10) -> list[dict[str, Any]]:
    """One pick per task (dataset, split, conditioning): the smallest row with error <= (1 + tolerance) x the
    group's best error (repeats of one size averaged first, `merge_repeats`). Rows without a finite error are
    listed as left out."""
    checks.one_of("metric", metric, HOPPER_ERRORS)
    checks.number("tolerance", tolerance, lo=0.0)
    tasks: dict[tuple, list[dict[str, Any]]] = {}
    for row in merge_repeats(rows):
        tasks.setdefault(task_of(row), []).append(row)
    picks = []
    for (data_name, split, conditioning), group in sorted(tasks.items()):
        scored = [r for r in group if math.isfinite(_value(r.get("errors", {}).get(metric)))]
        if not scored:
            continue
        best = min(scored, key=lambda r: (r["errors"][metric], size_key(r)))
        threshold = best["errors"][metric] * (1.0 + tolerance)
        within = sorted((r for r in scored if r["errors"][metric] <= threshold), key=size_key)
        pick = within[0]
        picks.append({
            "data_name": data_name, "split": split, "conditioning": list(conditioning), "metric": metric,
            "tolerance": tolerance, "best": _summary(best, metric), "threshold": threshold,
            "pick": _summary(pick, metric), "within_tolerance": [r["label"] for r in within],
            "left_out": [r["label"] for r in group if r not in scored],
            "candidates": [_summary(r, metric) for r in sorted(scored, key=size_key)],
        })
    if not picks:
        raise DataError(f"no run has a finite {metric!r}: nothing to right-size (check the runs' evaluations)")
    return picks


def right_size_all(rows: list[dict[str, Any]], tolerance: float = 0.10) -> list[dict[str, Any]]:
    """`right_size` for every practitioner's quantity that some run has a finite error of."""
    picks = []
    for metric in HOPPER_ERRORS:
        try:
            picks += right_size(rows, metric, tolerance)
        except DataError:
            continue
    if not picks:
        raise DataError("no run has a finite error of any quantity: nothing to right-size (check the evaluations)")
    return picks


def _summary(row: dict[str, Any], metric: str) -> dict[str, Any]:
    return {"label": row["label"], "error": row["errors"][metric], "size": row.get("size", {}),
            "time_to_answer_s": row.get("time_to_answer_s"), "run_dir": row.get("run_dir"),
            "error_range": (row.get("error_ranges") or {}).get(metric)}


def render_markdown(picks: list[dict[str, Any]]) -> str:
    lines = []
    for t in picks:
        label = HOPPER_ERRORS[t["metric"]]
        pick, best = t["pick"], t["best"]
        lines += [f"### {t['data_name']}, split {t['split']}, conditioning {', '.join(t['conditioning'])}", "",
                  (f"Pick: **{pick['label']}** ({label} {pick['error']:.2f}; best {best['error']:.2f} by "
                   f"{best['label']}; tolerance {100 * t['tolerance']:.0f} %)."), "",
                  f"| run | parameters | latent tokens | training queries | time to answer [s] | {label} | |",
                  "|---|---|---|---|---|---|---|"]
        for c in t["candidates"]:
            s = c["size"]
            mark = "pick" if c["label"] == t["pick"]["label"] else ("within" if c["label"] in t["within_tolerance"]
                                                                     else "")
            time_s = c["time_to_answer_s"]
            spread = c.get("error_range")
            error = f"{c['error']:.2f}" + (f" ({spread[0]:.2f} - {spread[1]:.2f})" if spread else "")
            lines.append(f"| {c['label']} | {_cell(s.get('parameters'), ',')} | {_cell(s.get('n_latent_tokens'))} | "
                         f"{_cell(s.get('train_queries'))} | {_cell(time_s, '.3g')} | {error} | {mark} |")
        lines.append("")
    return "\n".join(lines)


def _cell(v: Any, fmt: str = "") -> str:
    return "-" if v is None else format(v, fmt)


def main(argv: list[str]) -> int:
    p = command_parser(f"neuraldem.bench {NAME}", __doc__, summary=True)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--runs", type=Path, nargs="+", help="folders holding evaluated runs (timed here)")
    src.add_argument("--from", dest="from_file", type=Path, help="a speed_accuracy.json (its surrogate points)")
    p.add_argument("--metric", default="drainage_t95_pct_of_mean", choices=[*HOPPER_ERRORS, "all"],
                   help="the error to right-size by; all = one pick per quantity")
    p.add_argument("--tolerance", type=float, default=0.10, help="0.10 = within 10 %% of the best error")
    p.add_argument("--skip-unevaluated", action="store_true")
    p.add_argument("--repeats", type=int, default=3, help="timed answers per run (median), with runs=")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", type=Path, default=None, help=f"default results/speed_accuracy/{NAME}.json (+ .md)")
    a = p.parse_args(argv)
    checks.positive_int("repeats", a.repeats)
    checks.positive_int("threads", a.threads)
    machine = machine_info()
    if a.from_file is not None:
        rows = [pt for pt in read_results(a.from_file, "speed_accuracy")["results"]["points"]
                if pt["method"] in CANDIDATE_METHODS and pt.get("conditioning")]
        source = f"surrogate and scalar-baseline points of {a.from_file}"
    else:
        runs, _ = collect_runs(a.runs, a.skip_unevaluated)
        rows = surrogate_points(runs, a.repeats, a.threads, None)
        source = "runs timed by this command"
    picks = right_size_all(rows, a.tolerance) if a.metric == "all" else right_size(rows, a.metric, a.tolerance)
    path = write_results(NAME, {"source": source, "picks": picks}, command=command_line(NAME, argv),
                         path=a.out or default_path(NAME), machine=machine)
    text = render_markdown(picks)
    path.with_suffix(".md").write_text(text)
    print(text)
    print(f"wrote {path} and {path.with_suffix('.md')}")
    return 0
