"""Figures of the refilling hopper: the paper's refill figure (layers at t_ref, DEM and model `horizon`
seconds later, new material in gray) and the residence-time distribution of material at the outlet."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from neuraldem.scenes.hopper_refill.metrics import EMPTY, NEW


def _slice_scatter(ax: Any, points: np.ndarray, labels: np.ndarray, n_layers: int, half_width: float,
                   title: str) -> None:
    cmap = plt.get_cmap("viridis", n_layers)
    sel = np.abs(points[:, 1]) <= half_width
    p, lab = points[sel], labels[sel]
    old = lab >= 0
    ax.scatter(p[old, 0], p[old, 2], c=lab[old], cmap=cmap, vmin=-0.5, vmax=n_layers - 0.5, s=12)
    ax.scatter(p[lab == NEW, 0], p[lab == NEW, 2], c="0.6", s=12, label="refilled since t_ref")
    ax.scatter(p[lab == EMPTY, 0], p[lab == EMPTY, 2], facecolors="none", edgecolors="0.85", s=12)
    ax.set_aspect("equal")
    ax.locator_params(axis="x", nbins=4)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x [m]")


def refill_transport_figure(e: Any, diameter: float, path: Path) -> Path:
    """Three panels on the slice |y| <= one diameter: (a) reference layers at t_ref, (b) DEM and (c) model
    `horizon` later; gray = material refilled after t_ref; hollow = predicted empty."""
    d = e.figure_data
    n_layers = len(e.fractions_truth) - 1
    fig, axes = plt.subplots(1, 3, figsize=(11, 4.5), sharey=True)
    _slice_scatter(axes[0], d["points_ref"], d["labels_ref"], n_layers, diameter,
                   f"(a) layers at t_ref = {e.t_ref:g} s")
    _slice_scatter(axes[1], d["points_t"], d["labels_truth"], n_layers, diameter,
                   f"(b) DEM, t_ref + {e.horizon:g} s")
    _slice_scatter(axes[2], d["points_t"], d["labels_predicted"], n_layers, diameter,
                   f"(c) NeuralDEM, t_ref + {e.horizon:g} s")
    axes[0].set_ylabel("z [m]")
    fig.suptitle(f"{e.sim_id}: transport in refilling mode (layer agreement {e.label_agreement:.2f})", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def residence_distribution_figure(e: Any, path: Path, n_bins: int = 30) -> Path:
    samples = [s for s in (e.rtd_truth, e.rtd_predicted, e.rtd_particles) if s.size]
    hi = max((float(s.max()) for s in samples), default=1.0)
    bins = np.linspace(0.0, max(hi, 1e-3), n_bins + 1)
    fig, ax = plt.subplots(figsize=(6, 4))
    for s, label, style in ((e.rtd_truth, "DEM fields at the outlet", "-"),
                            (e.rtd_predicted, "NeuralDEM, aggregated across resets", "--"),
                            (e.rtd_particles, "DEM particles (exit - insertion)", ":")):
        if s.size:
            h, _ = np.histogram(s, bins=bins, density=True)
            ax.step(bins[:-1], h, where="post", linestyle=style, label=label)
    ax.set_xlabel("residence time since the opening [s]")
    ax.set_ylabel("density [1/s]")
    ax.set_title(f"{e.sim_id}: residence time of material leaving the hopper", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
