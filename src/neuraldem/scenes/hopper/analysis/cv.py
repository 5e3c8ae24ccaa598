"""`neuraldem report hopper-cv dataset=DIR [grids=[GRID_DIR,...]] [seed_floor=FILE] out=FILE.md`:
the hopper's Table 4 as a cross-validation, every method on the same held-out runs.

For every cross-validation fold (`data.splits.cv_split`: random folds, and interior alpha bands) and every
conditioning row (micro: alpha, mu_s, mu_r; macro: alpha, theta, repose) the table holds:
- **constant**: the training mean of every answer (the trivial baseline);
- **GP**: a Gaussian process on the scene scalars of the row (`scenes.hopper.baselines`);
- **field model**: the trained NeuralDEM runs found under GRID_DIR (`scripts/hopper_ablation.sh` with
  FOLDS set), evaluated with `neuraldem evaluate`; the baselines of that fold are fitted on exactly the runs
  the field model trained and validated on (the ids travel in its evaluation file);
- **LIGGGHTS, another packing seed**: the solver rerun with 3 other seeds on >= 10 parameter sets
  (`neuraldem bench seed_floor`), the noise floor no model can be expected to beat.
Errors are means over each fold's test runs, then mean +- std over the folds (`score_answers`, one function
for every method). Folds without a field-model run are scored for the baselines alone.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.data.manifest import Manifest, require_dataset
from neuraldem.data.schema import atomic_write_json
from neuraldem.data.splits import cv_split
from neuraldem.errors import DataError
from neuraldem.eval.checkpoints import read_checkpoint
from neuraldem.eval.run_results import scan_results
from neuraldem.machine import machine_info
from neuraldem.paths import module_command
from neuraldem.scenes.hopper.analysis.baselines import score_baseline
from neuraldem.scenes.hopper.surrogate.datamodule import cv_records

ROWS = {"micro": ["t", "alpha", "mu_s", "mu_r"], "macro": ["t", "alpha", "theta", "repose"]}
COLUMNS = {  # error key -> column title
    "drainage_t95_pct_of_mean": "drainage t95 [% of mean]",
    "drainage_mae_pct_of_mean": "drainage 1 % rule [% of mean]",
    "residual_mae_pp": "residual [pp]",
    "residual_particles_mae_pp": "residual vs particle count [pp]",
    "outflow_rel_err_pct": "outflow [%]",
    "flow_regime_accuracy": "flow regime [% right]",
}
METHODS = ("constant", "gp", "field model")


def fold_parts(m: Manifest, kind: str, fold: int, n_folds: int, seed: int, dataset_dir: Path,
               n_sims: int | None) -> dict[str, list[str]]:
    """A fold as the field model's datamodule makes it (`cv_records` + `cv_split`)."""
    records = cv_records(m, n_sims, dataset_dir)
    alpha = m.parameters.get("ranges", {}).get("alpha") or [min(r.params["alpha"] for r in records),
                                                           max(r.params["alpha"] for r in records)]
    return cv_split(records, kind, fold, n_folds, seed, 0.1, (float(alpha[0]), float(alpha[1])),
                    dataset=str(dataset_dir))


def field_runs(grids: list[Path], dataset_dir: Path) -> list[dict[str, Any]]:
    """Evaluations of cross-validation runs (a fold recorded) of this dataset, under the grid folders; with
    several grids, each grid is its own method (e.g. one training option per grid): `field model: <grid>`."""
    def keep(r: dict[str, Any]) -> bool:
        return r.get("fold") is not None and Path(r.get("dataset", "")).resolve() == dataset_dir.resolve()
    out = []
    for grid in grids:
        for r in scan_results([grid], keep=keep):
            r["method"] = "field model" if len(grids) == 1 else f"field model: {Path(grid).name}"
            out.append(r)
    return out


def row_of(conditioning: list[str]) -> str | None:
    return next((name for name, cond in ROWS.items() if cond == list(conditioning)), None)


def score_fold(m: Manifest, parts: dict[str, list[str]], conditioning: list[str]) -> dict[str, dict[str, Any]]:
    """The constant and the GP fitted on train + val of a fold, scored on its test runs."""
    train = [m.record(i) for i in parts["train"] + parts["val"]]
    test = [m.record(i) for i in parts["test"]]
    out = {}
    for kind in ("constant", "gp"):
        r = score_baseline(kind, train, test, conditioning)
        out[kind] = {"aggregate": r["aggregate"], "answer_s": r["answer_s"], "n_train": r["n_train"],
                     "n_extrapolated": r["n_extrapolated"], "coverage_95": r["coverage_95"],
                     "n_parameters": r["n_parameters"]}
    return out


def field_entry(field_run: dict[str, Any]) -> dict[str, Any]:
    """A field model's fold: its aggregate (the evaluation's), time per answer and size."""
    ckpt = read_checkpoint(field_run["checkpoint"])
    raw, params = ckpt.raw, ckpt.net_parameters
    best = next((v for k, v in raw.get("callbacks", {}).items() if k.startswith("ModelCheckpoint")), {})
    score = best.get("best_model_score")
    return {"aggregate": field_run["aggregate"], "answer_s": field_run["aggregate"].get("answer_s"),
            "n_train": len(field_run["split_ids"]["train"]), "checkpoint": field_run["checkpoint"],
            "n_extrapolated": field_run["aggregate"].get("n_extrapolated", 0), "n_parameters": int(params),
            "run": field_run["run"], "validation": {"monitor": best.get("monitor"),
                                                    "best": None if score is None else float(score)}}


def collect(dataset_dir: Path, grids: list[Path], kinds: list[str], n_folds: int, seed: int,
            n_sims: int | None = None, only_folds: list[int] | None = None) -> dict[str, Any]:
    m = require_dataset(dataset_dir, dataset_dir.name)
    runs = field_runs(grids, dataset_dir)
    folds: list[dict[str, Any]] = []
    for kind in kinds:
        for row, conditioning in ROWS.items():
            if row == "macro" and not all("theta" in r.macro for r in cv_records(m, n_sims, dataset_dir)):
                continue
            for k in (range(n_folds) if only_folds is None else only_folds):
                mine = [r for r in runs if r["split"] == kind and r["fold"] == k and row_of(r["conditioning"]) == row]
                names = [r["method"] for r in mine]
                twice = sorted({n for n in names if names.count(n) > 1})
                if twice:
                    raise DataError(f"several evaluated runs of {twice[0]!r} for {row}/{kind}/fold {k} ("
                                    f"{[r['path'] for r in mine if r['method'] == twice[0]]}): keep one per fold "
                                    "and grid")
                parts = mine[0]["split_ids"] if mine else fold_parts(m, kind, k, n_folds, seed, dataset_dir, n_sims)
                if any(r["split_ids"]["test"] != parts["test"] for r in mine):
                    raise DataError(f"the runs of {row}/{kind}/fold {k} were trained on different folds (the dataset "
                                    "changed between them): retrain them on one state of the dataset")
                methods = score_fold(m, parts, conditioning)
                for r in mine:
                    methods[r["method"]] = field_entry(r)
                folds.append({"split": kind, "row": row, "fold": k, "n_test": len(parts["test"]),
                              "test_ids": parts["test"], "methods": methods})
    return {"dataset": str(dataset_dir), "n_usable": len(cv_records(m, n_sims, dataset_dir)), "n_sims": n_sims,
            "n_folds": n_folds, "folds": folds}


def summarise(folds: list[dict[str, Any]], split: str, row: str, method: str) -> dict[str, Any] | None:
    rows = [f["methods"][method] for f in folds if f["split"] == split and f["row"] == row and method in f["methods"]]
    if not rows:
        return None
    out: dict[str, Any] = {"n_folds": len(rows), "n_test": sum(f["n_test"] for f in folds if f["split"] == split
                                                               and f["row"] == row and method in f["methods"])}
    out["n_parameters"] = int(np.median([r.get("n_parameters", 0) for r in rows]))
    val = [r["validation"]["best"] for r in rows if (r.get("validation") or {}).get("best") is not None]
    if val:  # the checkpoint's validation score: what training options are chosen by (never the test runs)
        out["validation_score"] = {"mean": float(np.mean(val)), "std": float(np.std(val)) if len(val) > 1 else np.nan,
                                   "monitor": rows[0]["validation"]["monitor"]}
    for key in (*COLUMNS, "answer_s"):
        values = np.array([r["aggregate"].get(key, np.nan) if key != "answer_s" else r.get("answer_s", np.nan)
                           for r in rows], dtype=np.float64)
        if key == "flow_regime_accuracy":
            values = 100 * values
        n_finite = int(np.isfinite(values).sum())
        out[key] = {"mean": float(np.nanmean(values)) if n_finite else np.nan,
                    "std": float(np.nanstd(values)) if n_finite > 1 else np.nan}  # one fold has no spread
    return out


def floor_row(seed_floor: dict[str, Any] | None) -> dict[str, Any] | None:
    """The seed-floor benchmark's 'rerun vs stored' errors (`results/hopper/accuracy/seed_floor.json`) in the table's
    layout: LIGGGHTS rerun with another packing seed answering the stored run's question."""
    if not seed_floor:
        return None
    res = seed_floor.get("results", seed_floor)
    agg = res.get("rerun_vs_stored") or {}
    out: dict[str, Any] = {k: {"mean": float(agg[k]) * (100 if k == "flow_regime_accuracy" else 1),
                               "std": float("nan")} for k in COLUMNS if k in agg}
    out["answer_s"] = {"mean": float(res.get("cost", {}).get("cpu_s_per_rerun_median") or float("nan")),
                       "std": float("nan")}
    out["n_sets"], out["n_seeds"] = res.get("n_sets"), res.get("seeds")
    out["spread"] = res.get("seed_spread")
    return out


def cell(v: dict[str, float] | None) -> str:
    if v is None or not np.isfinite(v["mean"]):
        return "-"
    return f"{v['mean']:.2f}" if not np.isfinite(v["std"]) else f"{v['mean']:.2f} +- {v['std']:.2f}"


def render(result: dict[str, Any]) -> str:
    within = f" of its first {result['n_sims']} simulations" if result.get("n_sims") else ""
    lines = [f"Dataset `{result['dataset']}`: {result['n_usable']} usable LIGGGHTS runs{within}, "
             f"{result['n_folds']}-fold cross-validation; mean +- std over the folds of each fold's mean error on its "
             "held-out runs.", ""]
    header = ("| conditioning | method | folds (test runs) | " + " | ".join(COLUMNS.values())
              + " | time per answer [s] | validation score |")
    sep = "|---|---|---|" + "---|" * (len(COLUMNS) + 2)
    for split in sorted({f["split"] for f in result["folds"]}):
        title = ("random folds" if split == "random"
                 else "held-out interior alpha bands (each fold leaves out one band of the alpha range)")
        lines += [f"### {split}: {title}", "", header, sep]
        for row in ROWS:
            for method, s in result["summary"].get(split, {}).get(row, {}).items():
                cells = " | ".join(cell(s[k]) for k in COLUMNS)
                t = s["answer_s"]["mean"]
                val = cell(s["validation_score"]) if "validation_score" in s else "-"
                lines.append(f"| {row} | {method} | {s['n_folds']} ({s['n_test']}) | {cells} | "
                             f"{f'{t:.3g}' if np.isfinite(t) else '-'} | {val} |")
        floor = result.get("seed_floor")
        if floor:
            cells = " | ".join(cell(floor.get(k)) for k in COLUMNS)
            lines.append(f"| any | LIGGGHTS, another packing seed | {floor['n_sets']} sets x {floor['n_seeds']} "
                         f"seeds | {cells} | {floor['answer_s']['mean']:.3g} | - |")
        lines.append("")
    lines += ["Time per answer: the constant and the GP answer one run's numbers; the field model answers its fields "
              "at every initial particle position and snapshot time, from which the numbers follow (evaluation "
              "wall time per run). Validation score: the field model's `val/practitioner_score` at its kept "
              "checkpoint (errors on the validation runs in units of 4 %, 0.8 pp, 2.5 %), the only number "
              "training options are chosen by.", ""]
    return "\n".join(lines)


def build(result: dict[str, Any], seed_floor: dict[str, Any] | None) -> dict[str, Any]:
    summary: dict[str, Any] = {}
    for f in result["folds"]:
        summary.setdefault(f["split"], {}).setdefault(f["row"], {})
    names = list(METHODS[:2]) + sorted({m for f in result["folds"] for m in f["methods"]} - set(METHODS[:2]))
    for split, rows in summary.items():
        for row in rows:
            rows[row] = {m: s for m in names if (s := summarise(result["folds"], split, row, m)) is not None}
    result["summary"] = summary
    result["seed_floor"] = floor_row(seed_floor)
    return result


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = doc_parser("neuraldem.scenes.hopper.analysis.cv", __doc__)
    p.add_argument("grids", type=Path, nargs="*", help="folders holding evaluated cross-validation runs")
    p.add_argument("--dataset", type=Path, required=True, help="the hopper dataset dir")
    p.add_argument("--splits", nargs="+", default=["random", "band"], choices=["random", "band"])
    p.add_argument("--n-folds", type=int, default=5)
    p.add_argument("--seed", type=int, default=0, help="split seed (data.splits.seed of the training runs)")
    p.add_argument("--folds", type=int, nargs="+", default=None,
                   help="score only these folds (default all; e.g. the folds a study trained)")
    p.add_argument("--n-sims", type=int, default=None,
                   help="folds over the first N simulations (data.datamodule.n_sims of the training runs)")
    p.add_argument("--seed-floor", type=Path, default=None, help="seed_floor.json of neuraldem bench seed_floor "
                                                                  "(the LIGGGHTS row)")
    p.add_argument("--out", type=Path, required=True, help="markdown file (+ .json beside it)")
    a = p.parse_args(argv)
    if a.n_folds < 2:
        raise DataError(f"n_folds={a.n_folds}: cross-validation needs >= 2 folds")
    floor = None
    if a.seed_floor is not None:
        if not a.seed_floor.is_file():
            raise DataError(f"seed_floor={a.seed_floor} does not exist: run neuraldem bench seed_floor "
                            f"dataset={a.dataset}")
        floor = json.loads(a.seed_floor.read_text())
    bad = [k for k in a.folds or [] if not 0 <= k < a.n_folds]
    if bad:
        raise DataError(f"folds={bad}: folds are 0 .. {a.n_folds - 1}")
    result = build(collect(a.dataset, a.grids, a.splits, a.n_folds, a.seed, a.n_sims, a.folds), floor)
    result.update(machine=machine_info(), command=module_command("neuraldem.scenes.hopper.analysis.cv", argv))
    text = render(result)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(text + "\n")
    atomic_write_json(a.out.with_suffix(".json"), result)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
