"""Refilling-hopper quantities from fields at query points (paper sec. 4.2, refill figure). Ground truth and
surrogate go through the same functions.

- layer labels: occupied points labelled by the height their material had at the reference time t_ref
  (`n_layers` bands by height holding equal shares of the material at t_ref), material inserted after t_ref is
  a class of its own ("new", gray in the figure).
- layer fractions: share of the occupied points in each layer and in "new"; the error between two sets of
  fractions is their total-variation distance (0 = identical, 1 = disjoint).
- residence-time distribution (RTD) of exiting material: the aggregated residence of the material found in
  the outlet region (below `height` above the outlet plane, within the outlet radius), pooled over a time
  grid; scored by the Wasserstein-1 distance [s] and the difference of medians. For reference the particle
  RTD (exit time - insertion time of particles that left) comes from `particle_exit_residence`.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import wasserstein_distance

from neuraldem.errors import DataError

NEW, EMPTY = -1, -2  # labels of new material and of unoccupied points


def reference_layer_edges(reference_z: np.ndarray, n_layers: int = 8) -> np.ndarray:
    """Edges of `n_layers` layers that hold equal shares of the material at t_ref. Equal heights between the
    lowest and highest particle would spend layers on the few refilled particles still falling at the top
    and on the stream below the outlet."""
    z = np.asarray(reference_z, dtype=np.float64)
    z = z[np.isfinite(z)]
    if z.size == 0:
        raise DataError("no material with a reference height: cannot define layers")
    return np.quantile(z, np.linspace(0.0, 1.0, n_layers + 1))


def layer_labels(occupied: np.ndarray, transport_z: np.ndarray, new: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(Q,) layer index 0 .. n_layers-1 by reference height, NEW for new material, EMPTY where unoccupied."""
    n_layers = len(edges) - 1
    z = np.nan_to_num(np.asarray(transport_z, dtype=np.float64), nan=edges[0])
    layer = np.clip(np.searchsorted(edges, z, side="right") - 1, 0, n_layers - 1)
    out = np.where(new, NEW, layer)
    return np.where(occupied, out, EMPTY)


def layer_fractions(labels: np.ndarray, n_layers: int) -> np.ndarray:
    """(n_layers + 1,) share of occupied points per layer, last entry = new material; zeros if nothing."""
    occ = labels != EMPTY
    counts = np.array([np.sum(labels == k) for k in range(n_layers)] + [np.sum(labels == NEW)], dtype=np.float64)
    return counts / occ.sum() if occ.any() else counts


def fraction_error(a: np.ndarray, b: np.ndarray) -> float:
    """Total-variation distance between two sets of fractions."""
    return float(0.5 * np.abs(np.asarray(a) - np.asarray(b)).sum())


def label_agreement(truth: np.ndarray, predicted: np.ndarray) -> float:
    """Share of the points occupied in the truth whose predicted label (layer or new) is the same."""
    occ = truth != EMPTY
    return float(np.mean(truth[occ] == predicted[occ])) if occ.any() else float("nan")


def outlet_region(points: np.ndarray, outlet_radius: float, height: float) -> np.ndarray:
    """(Q,) bool: query points in the outlet region (inside the outlet radius, 0 <= z <= height)."""
    p = np.asarray(points)
    r = np.hypot(p[:, 0], p[:, 1])
    return (r <= outlet_radius) & (p[:, 2] >= 0.0) & (p[:, 2] <= height)


def outlet_residence_samples(occupied: np.ndarray, residence: np.ndarray, in_outlet: np.ndarray) -> np.ndarray:
    """Residence values of the material at the outlet region, pooled over all times: `occupied` and
    `residence` are (T, Q), `in_outlet` is (Q,)."""
    sel = np.asarray(occupied, dtype=bool) & np.isfinite(residence) & np.asarray(in_outlet, dtype=bool)[None]
    return np.asarray(residence)[sel]


def particle_exit_residence(exit_times: np.ndarray, insert_times: np.ndarray, t_from: float = -np.inf,
                            t_to: float = np.inf) -> np.ndarray:
    """Exit time - insertion time of the particles that left in [t_from, t_to]."""
    e, i = np.asarray(exit_times, dtype=np.float64), np.asarray(insert_times, dtype=np.float64)
    sel = np.isfinite(e) & (e >= t_from) & (e <= t_to)
    return e[sel] - i[sel]


def rtd_scores(truth: np.ndarray, predicted: np.ndarray) -> dict[str, float]:
    """Wasserstein-1 distance [s] and median / 90th-percentile differences between two residence samples."""
    if truth.size == 0 or predicted.size == 0:
        return {"rtd_wasserstein_s": float("nan"), "rtd_median_error_s": float("nan"),
                "rtd_p90_error_s": float("nan")}
    return {
        "rtd_wasserstein_s": float(wasserstein_distance(truth, predicted)),
        "rtd_median_error_s": float(np.median(predicted) - np.median(truth)),
        "rtd_p90_error_s": float(np.quantile(predicted, 0.9) - np.quantile(truth, 0.9)),
    }


def rtd_histogram(samples: np.ndarray, bins: np.ndarray) -> np.ndarray:
    """Probability density of residence samples over `bins` (zeros if there are none)."""
    if samples.size == 0:
        return np.zeros(len(bins) - 1)
    h, _ = np.histogram(samples, bins=bins, density=True)
    return h
