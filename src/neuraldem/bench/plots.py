"""Benchmark figures (matplotlib, PNG), drawn from the results dicts alone, so any figure can be redrawn
from its JSON file without measuring again (`neuraldem bench render`)."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.ticker import NullFormatter


def scaling_figure(results: dict[str, Any], path: Path) -> Path:
    """Left: seconds per trajectory vs particles (LIGGGHTS) / query points (surrogate), log-log.
    Right: the surrogate vs its latent token count."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.6))
    solver = results.get("solver")
    if solver:
        pts = [p for p in solver["points"] if "failed" not in p]
        n = [p["n_particles"] for p in pts]
        left.plot(n, [p["extrapolated"]["full_run_s"] for p in pts], "o--", mfc="none", color="C0",
                  label="LIGGGHTS full run (settle measured, drain extrapolated)")
        left.plot(n, [p["measured"]["process_wall_s"] for p in pts], ".:", color="C0", alpha=0.6,
                  label=f"LIGGGHTS measured: settle + 2 x {pts[0]['steps_per_drain_chunk'] if pts else '?'} steps")
        full = [p for p in pts if "full_run_measured" in p]
        if full:
            left.plot([p["n_particles"] for p in full], [p["full_run_measured"]["loop_s"] for p in full], "s",
                      color="C3", label="LIGGGHTS full run, measured")
    sur = results["surrogate"]
    q = sur["by_queries"]
    if q:
        left.plot([r["n_queries"] for r in q], [r["median_wall_s"] for r in q], "^-", color="C1",
                  label=f"surrogate, all {sur['n_times']} times at Q query points")
        left.axhline(q[0]["median_wall_s"], color="C1", ls=":", lw=1,
                     label=f"surrogate at fixed Q = {q[0]['n_queries']} (flat in particle count)")
    failed = [p for p in (solver or {}).get("points", []) if "failed" in p]
    if failed:
        fig.text(0.01, 0.01, "LIGGGHTS failed at N = " + ", ".join(str(p["n_particles"]) for p in failed)
                 + " (reasons in the JSON)", fontsize=7, va="bottom")
    left.set(xscale="log", yscale="log", xlabel="particles N (LIGGGHTS) / query points Q (surrogate)",
             ylabel="seconds per trajectory (wall)", title="cost per trajectory")
    left.legend(fontsize=7)
    left.grid(True, which="both", alpha=0.3)
    tok = sur["by_tokens"]
    if tok:
        tokens = [r["n_latent_tokens"] for r in tok]
        right.plot(tokens, [r["median_wall_s"] for r in tok], "^-", color="C1")
        right.set(title=f"surrogate at Q = {tok[0]['n_queries']} query points")
    right.set(xscale="log", yscale="log", xlabel="latent tokens per branch", ylabel="seconds per trajectory (wall)")
    if tok:
        right.set_xticks(tokens, [str(k) for k in tokens])
        right.xaxis.set_minor_formatter(NullFormatter())
    right.grid(True, which="both", alpha=0.3)
    fig.tight_layout(rect=(0, 0.04 if failed else 0, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


METHOD_STYLE = {"surrogate": ("o", "C1"), "liggghts": ("s", "C0"), "GNS": ("D", "C3"),
                "DPMFoam, cheaper settings": ("s", "C0"), "DPMFoam, another packing": ("^", "C2"),
                "constant (training mean)": ("v", "0.4"), "Gaussian process": ("P", "C4"),
                "field model (CV)": ("*", "C1"), "LIGGGHTS, another packing seed": ("^", "C0")}


def speed_accuracy_figure(results: dict[str, Any], path: Path) -> Path:
    """One panel per practitioner's quantity: x = time to answer one trajectory, y = its error; the Pareto
    front joined by a line; the reference solver's time as a vertical line (its error is 0 by definition)."""
    quantities = results["quantities"]
    fig, axes = plt.subplots(1, len(quantities), figsize=(5.2 * len(quantities), 4.4), squeeze=False)
    points = results["points"]
    for ax, (key, label) in zip(axes[0], quantities.items(), strict=False):
        for method in sorted({p["method"] for p in points}):
            marker, color = METHOD_STYLE.get(method, ("D", "C2"))
            mine = [p for p in points if p["method"] == method and _finite(p["errors"].get(key))]
            kept = [p for p in mine if not p.get("n_diverged")]
            broke = [p for p in mine if p.get("n_diverged")]  # scored on the steps before divergence only
            ax.scatter([p["time_to_answer_s"] for p in kept], [p["errors"][key] for p in kept], marker=marker,
                       color=color, label=method, zorder=3)
            if broke:
                ax.scatter([p["time_to_answer_s"] for p in broke], [p["errors"][key] for p in broke], marker="x",
                           color=color, label=f"{method}, diverged (not ranked)", zorder=3)
            for p in mine:
                ax.annotate(p["label"] + (" (diverged)" if p.get("n_diverged") else ""),
                            (p["time_to_answer_s"], p["errors"][key]), fontsize=6, xytext=(3, 3),
                            textcoords="offset points")
        for i, curve in enumerate(results.get("curves", [])):
            xy = [(c["time_to_answer_s"], c["errors"][key]) for c in curve["points"] if _finite(c["errors"].get(key))]
            ax.plot([x for x, _ in xy], [y for _, y in xy], "o-", ms=3, lw=1.2, color=f"C{5 + i}",
                    label=curve["label"], zorder=2)
        front = [points[i] for i in results["pareto_front"][key]]
        ax.plot([p["time_to_answer_s"] for p in front], [p["errors"][key] for p in front], "k-", lw=1,
                alpha=0.6, label="Pareto front", zorder=2)
        floor = (results.get("floor") or {}).get(key)
        if _finite(floor):
            ax.axhline(floor, color="C0", ls=":", lw=1.2, label="LIGGGHTS seed floor (rerun, another packing)")
        ref = results.get("reference")
        if ref and _finite(ref.get("time_to_answer_s")):
            ax.axvline(ref["time_to_answer_s"], color="C0", ls="--", lw=1,
                       label=ref.get("label", "LIGGGHTS reference (error 0)"))
        positive = [p["errors"][key] for p in points if _finite(p["errors"].get(key)) and p["errors"][key] > 0]
        # symlog: an error of exactly 0 (e.g. no residual anywhere) stays on the chart
        ax.set_yscale("symlog", linthresh=min(positive, default=1.0) / 2)
        ax.set_ylim(bottom=0, top=2 * max(positive, default=1.0))  # headroom for the labels
        ax.set(xscale="log", xlabel=results.get("xlabel", "time to answer one trajectory [s, wall]"), ylabel=label,
               title=label)
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=7)
    failed = [f"{p['label']}: {p['n_failed']} of {p['n_sims']} ({p['failures'][0]['reason'][:80]})"
              for p in points if p.get("n_failed")]
    if failed:
        fig.text(0.01, 0.01, results.get("failed_label", "Failed runs: ") + "; ".join(failed), fontsize=7,
                 va="bottom")
    fig.tight_layout(rect=(0, 0.05 if failed else 0, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and math.isfinite(v)


def fb_speed_figure(results: dict[str, Any], path: Path) -> Path:
    """Left: seconds per simulated second (wall and CPU, log scale) of DPMFoam and of the surrogate at each
    thread setting. Right: the speed-ups solver / surrogate of every pairing, with the target (`target_speedup`)."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.6), gridspec_kw={"width_ratios": [1, 1.3]})
    entries = [(label, s) for label, s in results["solver"].items()]
    entries += [(f"surrogate, {t}" if "thread" in t else f"surrogate, {t} thread(s)", s)
                for t, s in results["surrogate"].items()]
    x = range(len(entries))
    for offset, key, name, color in ((-0.2, "median_wall_s", "wall", "C0"), (0.2, "median_cpu_s", "CPU", "C1")):
        values = [s[key] for _, s in entries]
        left.bar([i + offset for i in x], values, width=0.4, color=color, label=name)
        for i, v in zip(x, values, strict=False):
            left.annotate(f"{v:.3g}", (i + offset, v), ha="center", va="bottom", fontsize=7)
    left.set_xticks(list(x), [textwrap.fill(label.replace(",", ""), 10) for label, _ in entries], fontsize=7)
    left.set(yscale="log", ylabel="seconds per simulated second", title="cost of one simulated second")
    left.legend(fontsize=8)
    left.grid(True, axis="y", which="both", alpha=0.3)
    rows = results["side_by_side"]
    y = range(len(rows))
    for offset, key, name, color in ((-0.2, "speedup_wall", "wall", "C0"), (0.2, "speedup_cpu", "CPU", "C1")):
        values = [r[key] or 0.0 for r in rows]
        right.barh([i + offset for i in y], values, height=0.4, color=color, label=name)
        for i, v in zip(y, values, strict=False):
            right.annotate(f"{v:,.0f}x", (v, i + offset), va="center", fontsize=7, xytext=(3, 0),
                           textcoords="offset points")
    target = results.get("target_speedup")
    if target:
        right.axvline(target, color="k", ls="--", lw=1, label=f"target {target:g}x")
    right.set_yticks(list(y), [f"{r['solver']}\nvs surrogate, "
                               f"{r.get('surrogate', str(r['surrogate_threads']) + ' thread(s)')}" for r in rows],
                     fontsize=7)
    top = max([v for r in rows for v in (r["speedup_wall"], r["speedup_cpu"]) if v] + [target or 1.0, 1.0])
    right.set(xscale="log", xlim=(1.0, 8 * top), xlabel="speed-up (solver / surrogate, medians; bars from 1x)",
              title=f"{results['scene']}, U0 = {results['inlet_velocity']:g} m/s")
    right.invert_yaxis()  # rows in the order of the table
    right.legend(fontsize=8)
    right.grid(True, axis="x", which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def fb_stability_figure(results: dict[str, Any], path: Path) -> Path:
    """Stability map, velocity on x. Top: steps until failure (divergence or drift beyond the limit; open
    markers: no failure within the requested steps; squares: a bed height off CFD-DEM's). Middle: solid-volume
    drift at the end or at the last state before divergence. Bottom (where measured): the rollouts' time-mean bed
    height against CFD-DEM's training runs and the band of the bed limit. Trained velocity ranges shaded."""
    beds = [s for s in results["series"] if any(p.get("bed_height_mm") is not None for p in s["points"])]
    fig, axes = plt.subplots(3 if beds else 2, 1, figsize=(8, 10 if beds else 7), sharex=True)
    top, middle = axes[0], axes[1]
    ranges = {tuple(s["trained_velocity_range"]) for s in results["series"]}
    for k, s in enumerate(results["series"]):
        color = f"C{k}"
        lo, hi = s["trained_velocity_range"]
        label = "trained range" if len(ranges) == 1 else f"trained range ({s['label']})"
        if k == 0 or len(ranges) > 1:
            for ax in axes:
                if hi > lo:
                    ax.axvspan(lo, hi, color="0.5" if len(ranges) == 1 else color, alpha=0.15,
                               label=label if ax is top else None)
                else:
                    ax.axvline(lo, color="0.5" if len(ranges) == 1 else color, lw=4, alpha=0.3,
                               label=label if ax is top else None)
        pts = s["points"]
        v = [p["inlet_velocity"] for p in pts]
        top.plot(v, [p["steps_stable"] for p in pts], "-", color=color, alpha=0.6)
        ok = [p for p in pts if p.get("ok", not p["failed"])]
        bad = [p for p in pts if p["failed"]]
        off = [p for p in pts if p.get("bed_failed") and not p["failed"]]
        if ok:
            top.plot([p["inlet_velocity"] for p in ok], [p["steps_stable"] for p in ok], "o", mfc="none",
                     color=color, label=f"{s['label']}: stable ({len(ok)})")
        if bad:
            top.plot([p["inlet_velocity"] for p in bad], [p["steps_to_failure"] for p in bad], "x", color=color,
                     ms=8, label=f"{s['label']}: failed ({len(bad)})")
        if off:
            top.plot([p["inlet_velocity"] for p in off], [p["steps_stable"] for p in off], "s", color=color,
                     ms=7, label=f"{s['label']}: bed off CFD-DEM ({len(off)})")
        middle.plot(v, [p["drift_pct_end"] for p in pts], "o-", color=color, label=s["label"])
        if s in beds:
            h = [(p["inlet_velocity"], p["bed_height_mm"]) for p in pts if p.get("bed_height_mm") is not None]
            axes[2].plot(*zip(*h, strict=False), ".-", color=color, label=f"{s['label']} (rollout)")
    steps = results["steps"]
    top.axhline(steps, color="k", ls=":", lw=1, label=f"requested {steps} steps")
    horizon = results["series"][0]["training_horizon_steps"]
    if horizon < steps:
        top.axhline(horizon, color="k", ls="--", lw=0.8, alpha=0.5, label=f"training horizon {horizon} steps")
    bed_rule = f" or bed height beyond {results['bed_limit_pct']:g} %" if beds else ""
    top.set(ylabel="steps until failure", ylim=(0, 1.08 * steps),
            title="rollout stability: divergence, solid-volume drift beyond "
                  f"{results['drift_limit_pct']:g} %{bed_rule}")
    top.legend(fontsize=7)
    limit = results["drift_limit_pct"]
    for sign in (1, -1):
        middle.axhline(sign * limit, color="C3", ls="--", lw=1, label="drift limit" if sign > 0 else None)
    middle.set(ylabel="solid volume drift [%]\n(end, or before divergence)")
    middle.legend(fontsize=7)
    if beds:
        ref = beds[0]["bed_reference"]
        rv, rh = ref["velocities"], ref["bed_height_mm"]
        if rv:
            band = results["bed_limit_pct"] / 100.0
            axes[2].fill_between(rv, [h * (1 - band) for h in rh], [h * (1 + band) for h in rh], color="k", alpha=0.08,
                                 label=f"CFD-DEM +- {results['bed_limit_pct']:g} %")
            axes[2].plot(rv, rh, "k^", ms=5, label=f"CFD-DEM, training runs at {len(rv)} velocities")
        axes[2].set(ylabel=f"time-mean bed height [mm]\n(after {ref['settle_steps']} steps)")
        axes[2].legend(fontsize=7)
    axes[-1].set(xlabel="inlet velocity U0 [m/s]")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def hopper_stability_figure(results: dict[str, Any], path: Path) -> Path:
    """One panel per series: x = cone angle of the stored run, y = sliding friction; open circles stable over
    the whole trajectory, crosses failed (labelled with the time of failure); the trained mu_s range shaded."""
    series = results["series"]
    fig, axes = plt.subplots(1, len(series), figsize=(4.2 * len(series), 4.0), squeeze=False, sharey=True)
    lo, hi = results["trained_mu_s_range"]
    for ax, s in zip(axes[0], series, strict=False):
        ax.axhspan(lo, hi, color="0.5", alpha=0.15, label="trained mu_s range")
        ok = [p for p in s["points"] if not p["failed"]]
        bad = [p for p in s["points"] if p["failed"]]
        ax.plot([p["alpha"] for p in ok], [p["mu_s"] for p in ok], "o", mfc="none", color="C2",
                label=f"stable ({len(ok)})")
        ax.plot([p["alpha"] for p in bad], [p["mu_s"] for p in bad], "x", color="C3", ms=8,
                label=f"failed ({len(bad)})")
        for p in bad:
            ax.annotate(f"{p['failed_at_time_s']:.2g} s", (p["alpha"], p["mu_s"]), fontsize=6, xytext=(4, 2),
                        textcoords="offset points")
        ax.set(title=f"{s['label']}\n({s['method']})", xlabel="cone angle alpha of the run [deg]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=6, loc="upper center", ncol=3)
    top = max(results["mu_s_values"] + [p["mu_s"] for s in series for p in s["points"]])
    axes[0][0].set_ylim(-0.05 * top, 1.3 * top)  # headroom: the legend sits above the highest cells
    axes[0][0].set_ylabel("sliding friction mu_s asked")
    fig.suptitle(f"hopper stability: first unphysical time (limit {results['limit_pct']:g} %)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
