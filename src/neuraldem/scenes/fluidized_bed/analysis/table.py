"""`neuraldem report fb-table folders=[RUNS_DIR,...] out=FILE.md`: fluidized-bed runs side by side.

Finds every `evaluation/metrics.json` of a fluidized-bed model under the given folders (e.g. the runs of
`scripts/fb_ablation.sh`) and writes one summary row per run (its stability options, size, accuracy, mass
drift and stability at each horizon) and one row per run and held-out velocity, the long test trajectories in a
table of their own, and the scores against every CFD-DEM run at each velocity pooled (per velocity and summed:
the numbers to choose between runs on, see `reference_floor`), plus a JSON file with the same numbers next to
the markdown.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from neuraldem.cli import report_user_errors
from neuraldem.errors import DataError
from neuraldem.eval.run_results import find_results, table_main
from neuraldem.scenes.fluidized_bed.analysis.evaluation import POOLED_SCORE_KEYS, aggregate, pooled_sum
from neuraldem.scenes.fluidized_bed.surrogate.option_aliases import RESULT_CONSERVE_KEY


def run_name(result: dict) -> str:
    """The run's folder (<run>/evaluation/metrics.json) relative to the folder searched, e.g. fb_base/noise_pf;
    marked when its rollouts projected the solid volume onto a model trained without it (the drift is then 0 by
    construction, not the model's)."""
    name = result.get("run") or Path(result["path"]).parent.parent.name
    trained_with = (result.get("training") or {}).get("conserve_volume", False)
    projected_on_top = result.get(RESULT_CONSERVE_KEY) and not trained_with
    return f"{name} (solid volume projected)" if projected_on_top else name


def options_label(r: dict) -> str:
    """The run's training and rollout options in a few words (the stability options when recorded)."""
    if r.get("baseline"):  # neuraldem.scenes.fluidized_bed.analysis.baselines: no model
        return r.get("description", r["baseline"])
    t, st = r.get("training", {}), r.get("stability") or {}
    if not st:  # evaluated before the stability options existed
        return f"noise {t.get('input_noise', 'n/a')}, push-forward k = {t.get('push_forward_steps', 'n/a')}"
    unroll = st.get("unroll", [1.0])
    parts = ["one-step" if len(unroll) == 1 else "unroll " + "/".join(f"{p:g}" for p in unroll)]
    noise = st.get("input_noise", 0.0) or t.get("input_noise", 0.0)
    parts.append(f"noise {noise}")
    parts.append("flux" if t.get("solids_flux") else "no flux")
    parts.append(f"mixing {st.get('mixing', 'absolute')}"
                 + (f" ({st.get('advection_correction', 1.0):g}"
                    + (", consistent flux" if st.get("advection_flux") == "consistent" else "") + ")"
                    if st.get("mixing") == "advect" else ""))
    if st.get("conserve_volume"):
        parts.append("volume projected")
    if st.get("ensemble", 1) > 1:
        parts.append(f"stochastic, CRPS x{st['ensemble']}")
    if t.get("mirror"):
        parts.append("mirror")
    if st.get("mirror_alternate"):
        parts.append("mirror-alternating rollout")
    if st.get("rollout_noise"):
        parts.append(f"rollout noise x{st['rollout_noise']:g}")
    if t.get("weights") == "EMA":
        parts.append("EMA")
    return ", ".join(parts)


def is_long(r: dict, x: dict) -> bool:
    """A long test trajectory (fb_small's 30-s ones): CFD-DEM's trajectory is longer than the training horizon."""
    horizon = r.get("training_horizon_steps")
    return horizon is not None and (x.get("truth_steps") or x.get("window_steps") or 0) > horizon


def _f(v: float | None, fmt: str) -> str:
    return "n/a" if v is None else format(v, fmt)


def stable_cell(a: dict, multiple: int, n: int) -> str:
    k = a.get(f"stable_at_{multiple}x")
    return "n/a" if k is None else f"{k}/{n}"


def render(results: list[dict]) -> str:
    # baselines (neuraldem.scenes.fluidized_bed.analysis.baselines) have no rollout horizons: the layout comes from a
    # model's result
    first = next((r for r in results if r["horizons"]), results[0])
    mults = first["horizons"]
    length = (f"Rollouts of {first['rollout_steps']} steps ({max(mults)}x the training horizon of "
              f"{first['training_horizon_steps']} steps)" if mults else "Replayed CFD-DEM trajectories")
    lines = [(f"{length} from the first snapshot of each held-out trajectory; statistics over the steps both "
              "series have (baselines: as many as a training trajectory), mass drift over the whole series."), "",
             "| run | params | options | rel. L2 mean solid fraction | (whole rollout) "
             "| rel. L2 std solid fraction | rel. L2 mean fluid speed | max abs mass drift at the end [%] "
             "| (largest during the rollout) | Lacey MAE | "
             + " | ".join(f"stable {m}x" for m in mults) + " |",
             "|---|---|---|---|---|---|---|---|---|---|" + "---|" * len(mults)]
    for r in results:
        # the summary is over the held-out trajectories as long as a training one, so that runs with and without
        # the long test trajectories compare; the long ones have their own table below
        short = [x for x in r["trajectories"] if not is_long(r, x)]
        if not short or len(short) == len(r["trajectories"]):
            short = r["trajectories"]
            a = r["aggregate"]
        else:
            a = aggregate(short)
        t, n = r.get("training", {}), len(short)
        # the fluctuations (bubbles): a model that settles into the time mean scores ~1 here, fine on the mean
        stds = [x["rel_l2"]["solid_fraction_std"] for x in short]
        std = float(np.nanmean(stds)) if stds and not np.all(np.isnan(stds)) else None
        lines.append(f"| {run_name(r)} | {t.get('parameters', 0) / 1e6:.2f}M | {options_label(r)} | "
                     f"{_f(a['solid_fraction_mean_rel_l2'], '.3f')} | "
                     f"{_f(a['solid_fraction_mean_rel_l2_full'], '.3f')} | {_f(std, '.3f')} | "
                     f"{_f(a['fluid_speed_mean_rel_l2'], '.3f')} "
                     f"| {_f(a['mass_max_abs_drift_pct'], '.2f')} | {_f(a.get('mass_max_drift_during_pct'), '.2f')} "
                     f"| {_f(a['lacey_mae'], '.3f')} | "
                     + " | ".join(stable_cell(a, m, n) for m in mults) + " |")
    lines += ["", ("| run | U0 [m/s] | rel. L2 mean solid fraction | rel. L2 std solid fraction "
              "| mass drift at the end [%] | (largest during) "
              "| steps compared | Lacey MAE | Lacey final pred / CFD-DEM | bed height [mm] pred / CFD-DEM "
              "| bubble fraction pred / CFD-DEM | steps until divergence |"),
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        for x in r["trajectories"]:
            s, lc, bh = x["stability"], x["lacey"], x["bed_height"]
            div = "none" if s["steps_to_divergence"] is None else str(s["steps_to_divergence"])
            lines.append(f"| {run_name(r)} | {x['inlet_velocity']:.3f}"
                         f"{' (extrapolated)' if x.get('extrapolation') else ''} "
                         f"| {_f(x['rel_l2']['solid_fraction_mean'], '.3f')} "
                         f"| {_f(x['rel_l2']['solid_fraction_std'], '.3f')} "
                         f"| {x['mass']['drift_pct']:+.2f} | {_f(x['mass'].get('max_drift_pct'), '.2f')} "
                         f"| {x.get('window_steps', 'n/a')} "
                         f"| {_f(lc['mae'], '.3f')} | "
                         f"{_f(lc['final_pred'], '.2f')} / {_f(lc['final_truth'], '.2f')} | "
                         f"{_f(1000 * bh['mean_pred'], '.1f')} / {_f(1000 * bh['mean_truth'], '.1f')} | "
                         f"{_f(x['bubble_fraction']['mean_pred'], '.3f')} "
                         f"/ {_f(x['bubble_fraction']['mean_truth'], '.3f')}"
                         f" | {div} |")
    long_rows = [(r, x) for r in results for x in r["trajectories"] if is_long(r, x)]
    if long_rows:
        lines += ["", ("Against the long CFD-DEM trajectories: time mean and std of each whole series against the "
                       "whole CFD-DEM trajectory's (a baseline's 3 s against the 30 s); Lacey, bed height and "
                       "bubble fraction over the steps both have (a baseline: the first 3 s)."), "",
                  "| run | U0 [m/s] | steps (CFD-DEM) | rel. L2 mean solid fraction | rel. L2 std solid fraction "
                  "| Lacey MAE | bed height [mm] pred / CFD-DEM | bubble fraction pred / CFD-DEM "
                  "| time-mean error: profile / lateral | std-field lean pred / CFD-DEM |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for r, x in long_rows:
            bh, bf, full = x["bed_height"], x["bubble_fraction"], x.get("rel_l2_full") or x["rel_l2"]
            lr = x.get("structure") or {}  # evaluation.compare: left-right structure over the window
            lines.append(f"| {run_name(r)} | {x['inlet_velocity']:.3f} "
                         f"| {x['window_steps']} ({x.get('truth_steps', x['window_steps'])}) "
                         f"| {_f(full['solid_fraction_mean'], '.3f')} "
                         f"| {_f(full['solid_fraction_std'], '.3f')} | {_f(x['lacey']['mae'], '.3f')} "
                         f"| {_f(1000 * bh['mean_pred'], '.1f')} / {_f(1000 * bh['mean_truth'], '.1f')} "
                         f"| {_f(bf['mean_pred'], '.3f')} / {_f(bf['mean_truth'], '.3f')} "
                         f"| {_f(lr.get('mean_profile_rel_l2'), '.3f')} / {_f(lr.get('mean_lateral_rel_l2'), '.3f')} "
                         f"| {_f(lr.get('std_lean_pred'), '+.3f')} / {_f(lr.get('std_lean_truth'), '+.3f')} |")
    lines += pooled_table(results)
    m = first["machine"]
    lines += ["", f"Machine: {m.get('cpu_model', '')}; evaluated {first['date_utc']}.", ""]
    return "\n".join(lines)


def pooled_table(results: list[dict]) -> list[str]:
    """Each run's whole series against every CFD-DEM trajectory at the velocity (`evaluation.compare_pooled`),
    per velocity and summed; runs evaluated before the pooled reference existed are left out."""
    rows = [(r, x) for r in results for x in r["trajectories"] if "pooled" in x]
    if not rows:
        return []
    lines = ["", ("Against every CFD-DEM trajectory at the velocity, pooled (the whole series' per-cell statistics "
                  "against all packings' together; Lacey against their mean curve; a replayed baseline leaves its "
                  "own trajectory out of the reference, a model's rollout keeps the one it started from; "
                  "sum = mean + std + Lacey)."), "",
             "| run | U0 [m/s] | CFD-DEM runs (snapshots) | series snapshots | rel. L2 mean solid fraction "
             "| rel. L2 std solid fraction | Lacey MAE | sum | std-field wall share pred / CFD-DEM |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r, x in rows:
        q = x["pooled"]
        lr = q.get("structure") or {}  # how much of the bubbling reaches the walls (metrics.wall_share)
        tm, sd, lm = q["rel_l2"]["solid_fraction_mean"], q["rel_l2"]["solid_fraction_std"], q["lacey_mae"]
        total = pooled_sum((tm, sd, lm))
        lines.append(f"| {run_name(r)} | {x['inlet_velocity']:.3f} | {len(q['sims'])} ({q['snapshots']}) "
                     f"| {q['pred_snapshots']} | {_f(tm, '.3f')} | {_f(sd, '.3f')} | {_f(lm, '.3f')} "
                     f"| {_f(total, '.3f')} | {_f(lr.get('std_wall_share_pred'), '.3f')} / "
                     f"{_f(lr.get('std_wall_share_truth'), '.3f')} |")
    lines += ["", "| run | velocities | mean rel. L2 mean solid fraction | std | Lacey MAE | sum |",
              "|---|---|---|---|---|---|"]
    for r in results:
        a = r["aggregate"]  # the evaluation's own means (`evaluation.aggregate`: pooled_* when every run has it)
        if "pooled_lacey_mae" not in a:
            continue
        means = [a[k] for k in POOLED_SCORE_KEYS]
        total = pooled_sum(means)
        lines.append(f"| {run_name(r)} | {len(r['trajectories'])} | " + " | ".join(_f(v, ".3f") for v in means)
                     + f" | {_f(total, '.3f')} |")
    return lines


def fb_results(folders: list[Path]) -> list[dict]:
    results = [r for r in find_results(folders) if "trained_velocity_range" in r]
    if not results:
        raise DataError(f"no fluidized-bed evaluation under {[str(f) for f in folders]} (only other kinds): "
                        "train with experiment=fb (evaluate=true) or run neuraldem evaluate ckpt=...")
    return results


def summary(r: dict) -> dict:
    return {"run": run_name(r), "options": options_label(r),
            **{k: r.get(k) for k in ("training", "stability", "aggregate", "trajectories", "checkpoint",
                                                          "dataset", "machine", "command", "date_utc", "path")}}


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    return table_main(argv, "neuraldem.scenes.fluidized_bed.analysis.table", __doc__, fb_results, render, summary)


if __name__ == "__main__":
    sys.exit(main())
