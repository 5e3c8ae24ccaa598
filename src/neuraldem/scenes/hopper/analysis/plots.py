"""Figures of a hopper evaluation (matplotlib, written as PNG)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from neuraldem.scenes.hopper.analysis.scoring import SimEvaluation

QUANTITIES = {"drainage_time": ("drainage time [s]", 1.0), "residual_fraction": ("residual [%]", 100.0),
              "outflow_rate": ("outflow [N0/s]", 1.0)}


def scatter_predicted_vs_dem(evals: list[SimEvaluation], path: Path) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(12, 4))
    for ax, (key, (label, scale)) in zip(axes, QUANTITIES.items(), strict=False):
        t = np.array([e.truth[key] for e in evals]) * scale
        p = np.array([e.predicted[key] for e in evals]) * scale
        ax.scatter(t, p, s=18, alpha=0.8)
        lim = [np.nanmin([t.min(), p.min(), 0]), np.nanmax([t.max(), p.max()]) * 1.05 + 1e-9]
        ax.plot(lim, lim, "k--", lw=0.8)
        ax.set(xlabel=f"DEM {label}", ylabel=f"NeuralDEM {label}", xlim=lim, ylim=lim)
    fig.suptitle("Predicted vs DEM, test simulations")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def stripes_over_time(cases: dict[str, SimEvaluation], times: np.ndarray, path: Path) -> None:
    """Volume of each initial height layer over time, DEM vs prediction, one row per case."""
    stripe_panels([[(f"{title} ({e.sim_id}): DEM", times, e.stripes_truth),
                    (f"{title} ({e.sim_id}): NeuralDEM", times, e.stripes_predicted)] for title, e in cases.items()],
                  path)


def stripe_panels(rows: list[list[tuple[str, np.ndarray, np.ndarray]]], path: Path) -> None:
    """Rows of (title, times, stripes) panels: each layer's share of the initial material over time."""
    n_cols = max(len(r) for r in rows)
    fig, axes = plt.subplots(len(rows), n_cols, figsize=(5 * n_cols, 3.2 * len(rows)), squeeze=False)
    for row_axes, row in zip(axes, rows, strict=False):
        for ax, (title, times, stripes) in zip(row_axes, row, strict=False):
            n0 = max(stripes[0].sum(), 1.0)
            ax.stackplot(times, (stripes / n0).T, colors=plt.cm.viridis(np.linspace(0, 1, stripes.shape[1])))
            ax.set(title=title, xlabel="t [s]", ylabel="fraction of initial material", ylim=(0, 1.05))
        for ax in row_axes[len(row):]:
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def residence_slice(e: SimEvaluation, points: np.ndarray, slab: float, path: Path) -> None:
    """Residence time at t = 0 in the slab |y| < slab: DEM vs prediction (stale regions are dark)."""
    assert e.fields_truth is not None and e.fields_predicted is not None
    sel = np.abs(points[:, 1]) < slab
    vmax = float(np.nanmax(e.fields_truth.residence[0][sel]))
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.5), sharey=True)
    for ax, (who, f) in zip(axes, (("DEM", e.fields_truth), ("NeuralDEM", e.fields_predicted)), strict=False):
        sc = ax.scatter(points[sel, 0], points[sel, 2], c=f.residence[0][sel], s=12, cmap="magma_r", vmin=0,
                        vmax=vmax)
        ax.set(title=f"{who}: residence time at t = 0", xlabel="x [m]", aspect="equal")
    axes[0].set_ylabel("z [m]")
    fig.colorbar(sc, ax=axes, label="time until exit [s]")
    fig.savefig(path, dpi=120)
    plt.close(fig)


def generalization_map(test: list[SimEvaluation], train_params: list[dict[str, float]], path: Path,
                       x: str = "alpha", y: str = "theta") -> None:
    """Drainage time over (alpha, theta): DEM, prediction, absolute error; training simulations in gray."""
    if not test or any(y not in e.params for e in test):
        return
    tx = np.array([e.params[x] for e in test])
    ty = np.array([e.params[y] for e in test])
    dem = np.array([e.truth["drainage_time"] for e in test])
    pred = np.array([e.predicted["drainage_time"] for e in test])
    gx = [p[x] for p in train_params if y in p]
    gy = [p[y] for p in train_params if y in p]
    fig, axes = plt.subplots(1, 3, figsize=(14, 4), sharey=True)
    vmax = float(max(dem.max(), pred.max()))
    for ax, values, title, kw in ((axes[0], dem, "DEM drainage time [s]", {"vmin": 0, "vmax": vmax}),
                                  (axes[1], pred, "NeuralDEM drainage time [s]", {"vmin": 0, "vmax": vmax}),
                                  (axes[2], np.abs(pred - dem), "absolute error [s]", {"cmap": "Reds"})):
        ax.scatter(gx, gy, c="0.8", s=10, label="training")
        sc = ax.scatter(tx, ty, c=values, s=36, edgecolors="k", linewidths=0.4, **kw)
        fig.colorbar(sc, ax=ax)
        ax.set(title=title, xlabel=f"{x} [deg]")
    axes[0].set_ylabel(f"{y} [deg]")
    axes[0].legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
