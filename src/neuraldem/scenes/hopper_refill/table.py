"""`neuraldem report refill-table folders=[STUDY_DIR,...] out=FILE.md`: the refilling hopper's errors
against LIGGGHTS, model beside the persistence answer, one row per (run, evaluation).

Finds every `evaluation*/metrics.json` of a refill checkpoint under the folders (`scripts/refill_study.sh`
writes `evaluation/`, `evaluation_h1/` and `evaluation_tref0/` per run) and writes a markdown table plus a JSON
file with the same numbers next to it. Errors are means over the held-out simulations: layer-fraction error
(total variation, 0-1), label agreement (share of DEM-occupied points with the right layer / new label),
transport RMS (position at t_ref, % of the scene box), residence RMS [s], and the outlet residence-time
distribution (Wasserstein-1 distance and median error [s]); then what the model's outlet residence answer
cost beside the LIGGGHTS run.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from neuraldem.cli import report_user_errors
from neuraldem.errors import DataError
from neuraldem.eval.run_results import scan_results, table_main

HEADER = ("| run | part | conditioning | t_ref [s] | horizon [s] | layer-fraction error | label agreement | "
          "transport RMS [% box] | residence RMS [s] | RTD Wasserstein [s] | RTD median error [s] |")


COST_NOTE = ("Cost of the outlet residence answer over a whole run (the reset rollout; one timing per run during the "
             "evaluation, medians over the runs) against the LIGGGHTS run that gives it (manifest):")


def is_refill(result: dict) -> bool:
    return "persistence" in result and "horizon" in result


def find_refill_results(folders: list[Path]) -> list[dict]:
    found = scan_results(folders, "evaluation*/metrics.json", keep=is_refill)
    if not found:
        raise DataError(f"no refill evaluation*/metrics.json under {[str(f) for f in folders]}: run "
                        "scripts/refill_study.sh, or neuraldem evaluate ckpt=... on a refill checkpoint")
    return found


def reference_times(result: dict) -> str:
    t = sorted({round(float(s["t_ref"]), 3) for s in result["simulations"]})
    return "/".join(f"{v:g}" for v in t)


def cells(agg: dict, window: float) -> list[str]:
    """The error columns of one aggregate (normalised MSEs turned back into RMS values)."""
    tr = 100.0 * np.sqrt(agg["transport_mse"])
    res = window * np.sqrt(agg["residence_mse"])
    return [f"{agg['layer_fraction_error']:.3f}", f"{agg['label_agreement']:.2f}", f"{tr:.1f}", f"{res:.2f}",
            f"{agg['rtd_wasserstein_s']:.2f}", f"{agg['rtd_median_error_s']:+.2f}"]


def render(results: list[dict]) -> str:
    rows = sorted(results, key=lambda r: (r["run"], r.get("part", "test"), r["horizon"], reference_times(r)))
    n = sorted({r["aggregate"]["n_sims"] for r in rows})
    lines = [f"{'/'.join(map(str, n))} held-out simulations per row; model / persistence (nothing moved since t_ref)",
             "", HEADER, "|" + "---|" * 11]
    for r in rows:
        model, still = cells(r["aggregate"], r["window"]), cells(r["persistence"], r["window"])
        pairs = [f"{a} / {b}" for a, b in zip(model, still, strict=False)]
        head = [r["run"], r.get("part", "test"), ", ".join(r["conditioning"]), reference_times(r), f"{r['horizon']:g}"]
        lines.append("| " + " | ".join(head + pairs) + " |")
    lines += ["", COST_NOTE, "", "| run | horizon [s] | t_ref [s] | model [CPU s] | LIGGGHTS [CPU s] | ratio |",
              "|---|---|---|---|---|---|"]
    for r in rows:
        a = r["aggregate"]
        model, solver = a.get("rtd_answer_cpu_s", float("nan")), a.get("solver_cpu_s", float("nan"))
        lines.append(f"| {r['run']} | {r['horizon']:g} | {reference_times(r)} | {model:.2f} | {solver:.0f} | "
                     f"{solver / model:.0f}x |")
    lines.append("")
    return "\n".join(lines)


def summary(r: dict) -> dict:
    return {k: r.get(k) for k in ("run", "conditioning", "window", "horizon", "aggregate", "persistence",
                                  "checkpoint", "dataset", "command", "date_utc",
                                  "path")} | {"t_ref": reference_times(r)}


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    return table_main(argv, "neuraldem.scenes.hopper_refill.table", __doc__, find_refill_results, render, summary)


if __name__ == "__main__":
    sys.exit(main())
