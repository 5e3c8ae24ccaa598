"""How many queries the hopper field model's numbers need: accuracy against answer time over the query budget.

    neuraldem bench query_budget [model=hopper_small] [shares=[1,0.5,0.25,0.125,0.0625]] [strides=[1,2,4,8]]

The practitioner's numbers (t95, the 1 % drainage time, residual, outflow, mass-flow index) are fractions and
times read off a discharge curve: a seeded share of the lattice's material points (`query_points`) and every
n-th snapshot (`time_stride`) answer them with far fewer decoder queries than one per particle and snapshot (the
share is stratified by height and radius, the order in which the fill drains).
For every budget the field model answers each of the model's validation runs (its `meta.json` names them; they
must be in the dataset, default the model's own under the data dir) through the what-if path, and is scored
against LIGGGHTS with the function every hopper table uses. The answer time is the median of `repeats` answers
at one thread. The chosen budget is the one with the fewest queries whose every error stays within 10 % of the
full budget's (a floor of half a percentage point / 0.05 pp residual / one regime call keeps ties of tiny errors from
deciding). The GP and LIGGGHTS (the manifest's CPU seconds per run; another packing's errors from
results/hopper/accuracy/seed_floor.json) stand beside the curves. Writes query_budget.{json,md,png} into
results/hopper/speed/ (out=).
"""

from __future__ import annotations

import itertools
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem import pretrained
from neuraldem.bench.report import command_line, default_path, machine_at_start, resolve_out, write_report
from neuraldem.bench.timing import time_call
from neuraldem.cli import command_parser, report_user_errors
from neuraldem.data.manifest import Manifest
from neuraldem.errors import ConfigError, DataError
from neuraldem.paths import data_dir, results_dir

NAME = "query_budget"
ERRORS = {  # error key -> (label, absolute floor under which differences do not count)
    "drainage_t95_pct_of_mean": ("t95 [% of mean]", 0.5),
    "drainage_mae_pct_of_mean": ("1 % rule [% of mean]", 0.5),
    "residual_mae_pp": ("residual [pp]", 0.05),
    "outflow_rel_err_pct": ("outflow [%]", 0.5),
    "flow_regime_accuracy": ("regime right", None),
}
WITHIN = 0.10  # a budget is good enough when every error is within 10 % of the full budget's


def validation_runs(model: pretrained.Pretrained, dataset: Path) -> tuple[Manifest, list[Any]]:
    m = Manifest.load(dataset)
    ids = model.meta.get("training_data", {}).get("run_ids", {}).get("val", [])
    runs = [m.record(i) for i in ids if i in {r.sim_id for r in m.usable()}]
    if len(runs) < 3:
        raise DataError(f"{dataset} holds {len(runs)} of the {len(ids)} validation runs of model {model.name}",
                        f"generate them first: neuraldem datagen data={m.name} first=[{','.join(ids[:3])},...]")
    return m, runs


def acceptable(errors: dict[str, float], full: dict[str, float], n_runs: int) -> bool:
    for key, (_, floor) in ERRORS.items():
        if key == "flow_regime_accuracy":
            if errors[key] < full[key] - 1.0 / n_runs - 1e-9:
                return False
        elif errors[key] > full[key] * (1 + WITHIN) + floor:
            return False
    return True


def run(model_name: str, dataset: Path | None, shares: list[float], strides: list[int], repeats: int,
        runtime: str, threads: int) -> dict[str, Any]:
    from neuraldem.models.scalar_baselines import gp_answers
    from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings
    from neuraldem.scenes.hopper.analysis.scoring import score_answers
    from neuraldem.scenes.hopper.predict import hopper_gp, hopper_net
    from neuraldem.scenes.hopper.whatif import QueryBudget, field_answer

    model = pretrained.load(model_name, "hopper")
    dataset = dataset or data_dir() / "datasets" / model.meta["training_data"]["dataset"]
    m, runs = validation_runs(model, dataset)
    settings = HopperMetricSettings.from_config(model.meta.get("metric_settings", {}), f"{model.name} metrics")
    net, meta = hopper_net(model, runtime, threads)
    truths = [r.metrics for r in runs]
    points = [{k: r.params[k] for k in model.meta["inputs"]} for r in runs]
    rows = []
    for share, stride in itertools.product(sorted(shares, reverse=True), sorted(strides)):
        budget = QueryBudget(float(share), int(stride))
        answers = [field_answer(net, meta, p, settings, budget=budget) for p in points]
        timing, _ = time_call(lambda b=budget: field_answer(net, meta, points[0], settings, budget=b), repeats)
        rows.append({**budget.as_dict(), "n_points": int(np.median([len(a.points) for a in answers])),
                     "n_times": len(answers[0].fields.times), "answer_s": timing.median.wall_s,
                     "errors": score_answers(truths, [a.summary for a in answers])})
        print(f"points {share:g}, stride {stride}: {rows[-1]['n_points']} points x {rows[-1]['n_times']} "
              f"times, {rows[-1]['answer_s']:.3f} s", file=sys.stderr)
    full = next(r for r in rows if r["query_points"] == max(shares) and r["time_stride"] == min(strides))
    good = [r for r in rows if acceptable(r["errors"], full["errors"], len(runs))]
    # the fewest decoder queries (what the answer costs on any machine; the times measured here follow it)
    chosen = min(good, key=lambda r: (r["n_points"] * r["n_times"], r["answer_s"]))
    gp = hopper_gp(model)
    gp_timing, gp_out = time_call(lambda: gp_answers(gp, points), repeats)
    cpu = [r.cost["cpu_s"] for r in runs if "cpu_s" in r.cost]
    floor_file = results_dir() / "hopper" / "accuracy" / "seed_floor.json"
    seed_floor = json.loads(floor_file.read_text())["results"].get("errors") if floor_file.is_file() else None
    return {"model": model.name, "dataset": m.name, "runs": [r.sim_id for r in runs], "runtime": runtime,
            "threads": threads, "budgets": rows, "full": {k: full[k] for k in ("query_points", "time_stride")},
            "chosen": {k: chosen[k] for k in ("query_points", "time_stride")}, "within": WITHIN,
            "gp": {"answer_s": gp_timing.median.wall_s / len(points),
                   "errors": score_answers(truths, [{**a.mean, "mass_flow": float(a.mean["mass_flow_index"] >
                                                                                    settings.mass_flow_threshold)}
                                                    for a in gp_out])},
            "liggghts": {"answer_s": float(np.median(cpu)) if cpu else None, "seed_floor_errors": seed_floor}}


def markdown(r: dict[str, Any]) -> str:
    head = "| query points (share) | time stride | points x times | answer [s] | " + " | ".join(
        label for label, _ in ERRORS.values()) + " |"
    lines = [f"# Hopper field model: errors against answer time over the query budget ({r['model']}, "
             f"{len(r['runs'])} validation runs of {r['dataset']}, {r['runtime']}, {r['threads']} thread)", "",
             head, "|" + "---|" * (4 + len(ERRORS))]
    for b in r["budgets"]:
        mark = " **chosen**" if (b["query_points"], b["time_stride"]) == tuple(r["chosen"].values()) else ""
        lines.append(f"| {b['query_points']:g}{mark} | {b['time_stride']} | {b['n_points']} x {b['n_times']} | "
                     f"{b['answer_s']:.3f} | " + " | ".join(f"{b['errors'][k]:.3g}" for k in ERRORS) + " |")
    gp = r["gp"]
    lines.append(f"| GP | - | - | {gp['answer_s']:.4f} | " + " | ".join(f"{gp['errors'][k]:.3g}" for k in ERRORS)
                 + " |")
    if r["liggghts"]["answer_s"]:
        lines.append(f"| LIGGGHTS (CPU s per run) | - | - | {r['liggghts']['answer_s']:.0f} | "
                     + " | ".join("-" for _ in ERRORS) + " |")
    lines += ["", f"Chosen: the budget with the fewest queries whose every error is within {100 * r['within']:.0f} % "
                  "of the full "
                  f"budget's (points {r['full']['query_points']:g}, stride {r['full']['time_stride']}), plus a "
                  "floor of 0.5 % / 0.05 pp / one regime call. Regenerate: `neuraldem bench query_budget`."]
    return "\n".join(lines) + "\n"


def plot(r: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, key in zip(axes, ("drainage_t95_pct_of_mean", "outflow_rel_err_pct"), strict=True):
        for share in sorted({b["query_points"] for b in r["budgets"]}, reverse=True):
            rows = sorted((b for b in r["budgets"] if b["query_points"] == share), key=lambda b: b["answer_s"])
            ax.plot([b["answer_s"] for b in rows], [b["errors"][key] for b in rows], "o-",
                    label=f"field model, {share:g} of the points")
        ax.plot([r["gp"]["answer_s"]], [r["gp"]["errors"][key]], "k^", ms=9, label="GP")
        floor = (r["liggghts"].get("seed_floor_errors") or {}).get(key)
        if r["liggghts"]["answer_s"] and floor is not None:
            ax.plot([r["liggghts"]["answer_s"]], [floor], "ks", ms=9, label="LIGGGHTS, another packing")
        chosen = next(b for b in r["budgets"] if (b["query_points"], b["time_stride"]) == tuple(r["chosen"].values()))
        ax.plot([chosen["answer_s"]], [chosen["errors"][key]], "r*", ms=16, label="chosen budget")
        ax.set(xscale="log", xlabel="answer time [s] (one thread)", ylabel=ERRORS[key][0],
               title=f"{ERRORS[key][0]} vs answer time")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = command_parser(f"neuraldem.bench {NAME}", __doc__)
    p.add_argument("--model", default="hopper_small", help="a shipped or released hopper model")
    p.add_argument("--dataset", type=Path, default=None, help="its dataset (default: the model's in the data dir)")
    p.add_argument("--shares", type=float, nargs="+", default=[1.0, 0.5, 0.25, 0.125, 0.0625],
                   help="shares of the lattice's material points")
    p.add_argument("--strides", type=int, nargs="+", default=[1, 2, 4, 8])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--runtime", choices=("auto", "onnx", "torch"), default="auto")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", type=Path, default=None, help=f"JSON file or folder (default {default_path(NAME)})")
    args = p.parse_args(argv)
    if args.repeats < 1:
        raise ConfigError(f"repeats={args.repeats} is invalid: give at least 1")
    machine = machine_at_start()
    result = run(args.model, args.dataset, args.shares, args.strides, args.repeats, args.runtime, args.threads)
    out = resolve_out(args.out, NAME)
    write_report(NAME, result, markdown(result), command=command_line(NAME, argv), path=out, machine=machine)
    plot(result, out.with_suffix(".png"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
