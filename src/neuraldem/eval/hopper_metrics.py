"""Practitioner's hopper quantities (paper sec. 4.2) from fields evaluated at fixed query points.

Every function takes plain arrays: `occupied[t, q]` (is query point q occupied at snapshot t) and
`transport_z[t, q]` (initial height of the material found at q). The query points are the initial
particle positions, so `occupied.sum(1)` counts material in units of initial particles. Ground truth
(fields computed from DEM particles) and surrogate predictions go through exactly the same functions.

Definitions (documented in docs/metrics.md):
- residual fraction: occupied count at the last snapshot / N0.
- drainage time: first time the occupied count is within `margin` * N0 of its final value. The paper's
  "fewer than K particles above the outlet" never triggers on a flat bottom, where the dead zone lies
  above the outlet plane; measuring against the final (residual) state works for both.
- outflow rate: mean rate at which the count falls while the first 10 % to 60 % of the material that
  eventually drains leaves, as a fraction of N0 per second (skips start-up and the tail).
- layer stripes: occupied points binned by the initial height of the material found there (8 layers).
- mass-flow index: Spearman rank correlation between a layer's initial height and the time it has lost
  half of its material: +1 = first in, first out (mass flow), <= 0 = upper layers overtake (funnel flow).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import spearmanr


def occupied_counts(occupied: np.ndarray) -> np.ndarray:
    return occupied.sum(axis=1).astype(np.float64)


def residual_fraction(counts: np.ndarray, n0: int) -> float:
    return float(counts[-1] / n0)


def drainage_time(times: np.ndarray, counts: np.ndarray, n0: int, margin: float = 0.01) -> float:
    done = np.flatnonzero(counts - counts[-1] <= margin * n0)
    return float(times[done[0]])


def _crossing_time(times: np.ndarray, counts: np.ndarray, level: float) -> float:
    """First time the (non-increasing in trend) count falls to `level`, linearly interpolated."""
    below = np.flatnonzero(counts <= level)
    if len(below) == 0:
        return float("nan")
    k = below[0]
    if k == 0:
        return float(times[0])
    c0, c1 = counts[k - 1], counts[k]
    frac = (c0 - level) / (c0 - c1) if c0 != c1 else 1.0
    return float(times[k - 1] + frac * (times[k] - times[k - 1]))


def outflow_rate(times: np.ndarray, counts: np.ndarray, n0: int,
                 window: tuple[float, float] = (0.1, 0.6)) -> float:
    drained = counts[0] - counts[-1]
    if drained <= 0:
        return 0.0
    levels = [counts[0] - w * drained for w in window]
    t_a, t_b = (_crossing_time(times, counts, lv) for lv in levels)
    if not t_b > t_a:
        return float("nan")
    return float((levels[0] - levels[1]) / (t_b - t_a) / n0)


def layer_edges(initial_z: np.ndarray, n_layers: int = 8) -> np.ndarray:
    return np.linspace(float(np.min(initial_z)), float(np.max(initial_z)), n_layers + 1)


def layer_stripes(occupied: np.ndarray, transport_z: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(T, n_layers) number of occupied points whose material started in each height layer."""
    n_layers = len(edges) - 1
    layer = np.clip(np.searchsorted(edges, np.nan_to_num(transport_z, nan=edges[0]), side="right") - 1,
                    0, n_layers - 1)
    out = np.zeros((occupied.shape[0], n_layers))
    for k in range(n_layers):
        out[:, k] = (occupied & (layer == k)).sum(axis=1)
    return out


def mass_flow_index(times: np.ndarray, stripes: np.ndarray) -> float:
    """Rank correlation of layer height with its half-depletion time (never depleted = last)."""
    initial = stripes[0]
    half_times = np.array([_crossing_time(times, stripes[:, k], 0.5 * initial[k]) if initial[k] > 0
                           else np.nan for k in range(stripes.shape[1])])
    half_times = np.where(np.isnan(half_times), np.inf, half_times)
    if np.all(half_times == half_times[0]):
        return float("nan")
    rho = spearmanr(np.arange(len(half_times)), half_times).statistic
    return float(rho)


def flow_regime(index: float, threshold: float = 0.5) -> str:
    return "mass" if index > threshold else "funnel"


def hopper_summary(times: np.ndarray, occupied: np.ndarray, transport_z: np.ndarray, initial_z: np.ndarray,
                   n_layers: int = 8, drain_margin: float = 0.01) -> dict[str, float]:
    """All scalar hopper metrics of one trajectory (ground truth or prediction)."""
    n0 = occupied.shape[1]
    counts = occupied_counts(occupied)
    stripes = layer_stripes(occupied, transport_z, layer_edges(initial_z, n_layers))
    index = mass_flow_index(times, stripes)
    return {
        "drainage_time": drainage_time(times, counts, n0, drain_margin),
        "residual_fraction": residual_fraction(counts, n0),
        "outflow_rate": outflow_rate(times, counts, n0),
        "mass_flow_index": index,
    }
