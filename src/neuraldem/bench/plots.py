"""Benchmark figures (matplotlib, PNG), drawn from the results dicts alone, so any figure can be redrawn
from its JSON file without measuring again (`python -m neuraldem.bench render`)."""

from __future__ import annotations

import math
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


METHOD_STYLE = {"surrogate": ("o", "C1"), "liggghts": ("s", "C0")}


def speed_accuracy_figure(results: dict[str, Any], path: Path) -> Path:
    """One panel per practitioner's quantity: x = time to answer one trajectory, y = its error; the Pareto
    front joined by a line; the reference solver's time as a vertical line (its error is 0 by definition)."""
    quantities = results["quantities"]
    fig, axes = plt.subplots(1, len(quantities), figsize=(5.2 * len(quantities), 4.4), squeeze=False)
    points = results["points"]
    for ax, (key, label) in zip(axes[0], quantities.items()):
        for method in sorted({p["method"] for p in points}):
            marker, color = METHOD_STYLE.get(method, ("D", "C2"))
            mine = [p for p in points if p["method"] == method and _finite(p["errors"].get(key))]
            ax.scatter([p["time_to_answer_s"] for p in mine], [p["errors"][key] for p in mine], marker=marker,
                       color=color, label=method, zorder=3)
            for p in mine:
                ax.annotate(p["label"], (p["time_to_answer_s"], p["errors"][key]), fontsize=6,
                            xytext=(3, 3), textcoords="offset points")
        front = [points[i] for i in results["pareto_front"][key]]
        ax.plot([p["time_to_answer_s"] for p in front], [p["errors"][key] for p in front], "k-", lw=1,
                alpha=0.6, label="Pareto front", zorder=2)
        ref = results.get("reference")
        if ref:
            ax.axvline(ref["time_to_answer_s"], color="C0", ls="--", lw=1, label="LIGGGHTS reference (error 0)")
        positive = [p["errors"][key] for p in points if _finite(p["errors"].get(key)) and p["errors"][key] > 0]
        # symlog: an error of exactly 0 (e.g. no residual anywhere) stays on the chart
        ax.set_yscale("symlog", linthresh=min(positive, default=1.0) / 2)
        ax.set_ylim(bottom=0, top=2 * max(positive, default=1.0))  # headroom for the labels
        ax.set(xscale="log", xlabel="time to answer one trajectory [s, wall]", ylabel=label, title=label)
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=7)
    failed = [f"{p['label']}: {p['n_failed']} of {p['n_sims']} ({p['failures'][0]['reason'][:80]})"
              for p in points if p.get("n_failed")]
    if failed:
        fig.text(0.01, 0.01, "Failed LIGGGHTS runs: " + "; ".join(failed), fontsize=7, va="bottom")
    fig.tight_layout(rect=(0, 0.05 if failed else 0, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and math.isfinite(v)
