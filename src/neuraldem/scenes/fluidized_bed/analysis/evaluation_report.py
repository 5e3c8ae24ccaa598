"""The report.md of a bed evaluation: per trajectory and pooled over CFD-DEM's runs at its velocity, stability at
each horizon, and the structure of the bubbling (wall share, lean, rise)."""

from __future__ import annotations

from typing import Any

from neuraldem.paths import portable


def markdown_report(result: dict[str, Any]) -> str:
    h = result["training_horizon_steps"]
    intro = (f"checkpoint `{portable(result['checkpoint'])}`, dataset `{portable(result['dataset'])}` "
             f"({result['split']} split, "
             f"{result['part']}), trained on inlet velocities {result['trained_velocity_range'][0]:g} - "
             f"{result['trained_velocity_range'][1]:g} m/s, training horizon {h} steps of {result['dt']:g} s, "
             f"rollouts of {result['rollout_steps']} steps. Statistics over the steps both the rollout and the "
             "CFD-DEM trajectory have; mass drift over the whole rollout.")
    header = ("| U0 [m/s] | extrapolation | steps compared | rel. L2 mean solid fraction (whole rollout) "
              "| rel. L2 std solid fraction "
              "| rel. L2 mean fluid speed | mass drift [%] (steps) | Lacey MAE | bed height [mm] pred / CFD-DEM "
              "| bubble fraction pred / CFD-DEM |")
    lines = ["# Fluidized-bed surrogate vs CFD-DEM", "", intro, "", header,
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in result["trajectories"]:
        rl, ms, bh, bf = r["rel_l2"], r["mass"], r["bed_height"], r["bubble_fraction"]
        full = r["rel_l2_full"]["solid_fraction_mean"]
        lines.append(f"| {r['inlet_velocity']:.3f} | {'yes' if r.get('extrapolation') else 'no'} | "
                     f"{r['window_steps']} | {rl['solid_fraction_mean']:.3f} ({full:.3f}) | "
                     f"{rl['solid_fraction_std']:.3f} | "
                     f"{rl['fluid_speed_mean']:.3f} | {ms['drift_pct']:+.2f} ({ms['steps']}) | "
                     f"{r['lacey']['mae']:.3f} | {1000 * bh['mean_pred']:.1f} / {1000 * bh['mean_truth']:.1f} | "
                     f"{bf['mean_pred']:.3f} / {bf['mean_truth']:.3f} |")
    pooled = [r for r in result["trajectories"] if "pooled" in r]
    if pooled:
        lines += ["", "## Against every CFD-DEM trajectory at the velocity (pooled)", "",
                  "The whole rollout's per-cell statistics against those of all CFD-DEM runs at its inlet velocity "
                  "together (independent packings: a better estimate of the long-time statistics than one run); "
                  "Lacey MAE against their mean curve.", "",
                  "| U0 [m/s] | CFD-DEM runs (snapshots) | rollout snapshots | rel. L2 mean solid fraction "
                  "| rel. L2 std solid fraction | rel. L2 mean mixing | Lacey MAE (steps) |",
                  "|---|---|---|---|---|---|---|"]
        for r in pooled:
            q = r["pooled"]
            lines.append(f"| {r['inlet_velocity']:.3f} | {len(q['sims'])} ({q['snapshots']}) | {q['pred_snapshots']} "
                         f"| {q['rel_l2']['solid_fraction_mean']:.3f} | {q['rel_l2']['solid_fraction_std']:.3f} | "
                         f"{q['rel_l2']['mixing_mean']:.3f} | {q['lacey_mae']:.3f} ({q['lacey_steps']}) |")
    lines += structure_section(result["trajectories"])
    mults = [x["multiple"] for x in result["trajectories"][0]["stability"]["horizons"]]
    lines += ["", "## Stability", "",
              "| U0 [m/s] | steps until divergence | " + " | ".join(f"{k}x ({k * h} steps)" for k in mults) + " |",
              "|---|---|" + "---|" * len(mults)]
    for r in result["trajectories"]:
        s = r["stability"]
        div = "none" if s["steps_to_divergence"] is None else f"{s['steps_to_divergence']} ({s['divergence']})"
        marks = " | ".join("stable" if x["stable"] else "diverged" for x in s["horizons"])
        lines.append(f"| {r['inlet_velocity']:.3f} | {div} | {marks} |")
    machine = result["machine"]
    footer = (f"Machine: {machine.get('cpu_model', '')} (GPU: {machine.get('cuda') or 'none'}); "
              f"command: `{result['command']}`; {result['date_utc']}")
    lines += ["", footer, ""]
    return "\n".join(lines)


def structure_section(trajectories: list[dict[str, Any]]) -> list[str]:
    """The left-right table of the report (metrics.left_right_structure), against the run and, where
    scored, against the pooled runs."""
    rows = [(r["inlet_velocity"], ref, q["structure"]) for r in trajectories
            for ref, q in (("run", r), ("pooled", r.get("pooled"))) if q is not None and "structure" in q]
    if not rows:
        return []
    lines = ["", "## Left-right structure of the solid fraction", "",
             "The time-mean error split into the height profile (x-mean per height) and the lateral rest "
             "(profile^2 + lateral^2 = rel. L2^2); mirror asymmetry ||f - f mirrored|| / ||f|| of the time-mean "
             "and std fields, the std field's lean (right - left) / total and its share in the columns next to the "
             "walls (how much of the bubbling reaches them), rollout / CFD-DEM (the box is symmetric: CFD-DEM's "
             "asymmetry and lean are sampling noise).", "",
             "| U0 [m/s] | reference | time-mean error: profile / lateral | asymmetry of the time mean "
             "| asymmetry of the std field | lean of the std field | wall share of the std field |",
             "|---|---|---|---|---|---|---|"]
    for v, ref, q in rows:
        lines.append(f"| {v:.3f} | {ref} | {q['mean_profile_rel_l2']:.3f} / {q['mean_lateral_rel_l2']:.3f} | "
                     f"{q['mean_asymmetry_pred']:.3f} / {q['mean_asymmetry_truth']:.3f} | "
                     f"{q['std_asymmetry_pred']:.3f} / {q['std_asymmetry_truth']:.3f} | "
                     f"{q['std_lean_pred']:+.3f} / {q['std_lean_truth']:+.3f} | "
                     f"{q['std_wall_share_pred']:.3f} / {q['std_wall_share_truth']:.3f} |")
    return lines
