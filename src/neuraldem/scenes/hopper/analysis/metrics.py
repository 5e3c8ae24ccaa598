"""Practitioner's hopper quantities (paper sec. 4.2) from fields evaluated at fixed query points.

Every function takes plain arrays: `occupancy[t, q]` (probability, or 0/1, that query point q is occupied at
snapshot t) and `transport_z[t, q]` (initial height of the material found at q). The query points are the
initial particle positions, so `occupancy.sum(1)` counts material in units of initial particles. Ground truth
(fields computed from DEM particles, 0/1) and surrogate predictions (probabilities) go through exactly the
same functions, on the same time grid: 0 .. the scene's `max_time`, a run that ended earlier holding its final
state (`metric_times`).

The definitions are chosen to be robust to small field errors (docs/metrics.md):
- counts are soft: the sum of occupancy probabilities, never a 0.5 threshold;
- final level: the mean count over the last `tail_time` seconds of the time range (a slowly decaying small
  tail moves it a little, not to the end of the range);
- drainage time t95: the time when 95 % of the finally discharged material (start count - final level) has
  left, linearly interpolated between snapshots; the older rule (first time within 1 % of N0 of the final
  level) is kept as a secondary column (`drainage_time`);
- residual fraction: final level / N0; the particle count that never left (from the exit times) is stored
  beside it as the truth users know (`residual_fraction_particles`);
- outflow rate: the mean rate at which the count falls while 20 % to 70 % of the discharged material
  leaves, as a fraction of N0 per second (skips the start-up from rest and the tail);
- layer stripes: occupancy summed per layer of initial height (8 layers); mass-flow index: Spearman rank
  correlation between a layer's height and the time it has lost half of its material (+1 = first in, first
  out = mass flow; <= 0 = upper layers overtake = funnel flow).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from neuraldem.config import checks
from neuraldem.errors import ConfigError

# the scalars every hopper answer has (ground truth, surrogate, scalar baselines, solver reruns)
SCALARS = ("drainage_t95", "drainage_time", "residual_fraction", "outflow_rate", "mass_flow_index")


@dataclass(frozen=True)
class HopperMetricSettings:
    """Every knob of the hopper metrics, in one place (`data.metrics` of a hopper data config).

    Recorded in the dataset manifest next to the stored metrics; datagen rescores a dataset whose stored
    metrics were computed with other settings."""

    # occupancy radius in particle diameters: 0.8 keeps the voids of flowing (dilated) material covered; at 0.6
    # 15-25 % of the points inside flowing material read empty (`python -m
    # neuraldem.scenes.hopper.dataset.occupancy_coverage`)
    occupancy_radius_d: float = 0.8
    n_layers: int = 8
    tail_time: float = 1.0  # [s] final level = mean count over the last tail_time of the time range
    drain_fraction: float = 0.95  # drainage time t95: this share of the discharged material has left
    drain_margin: float = 0.01  # secondary drainage time: within this share of N0 of the final level
    outflow_window: tuple[float, float] = (0.2, 0.7)  # shares of the discharged material
    mass_flow_threshold: float = 0.5  # mass-flow index above this = mass flow

    @classmethod
    def from_config(cls, cfg: Any, key: str = "data.metrics") -> HopperMetricSettings:
        from omegaconf import OmegaConf  # a config may be handed in; the what-if path hands a dict

        values = dict(OmegaConf.to_container(cfg) if OmegaConf.is_config(cfg) else dict(cfg or {}))
        checks.known_keys(key, values, cls.__dataclass_fields__)
        if "outflow_window" in values:
            values["outflow_window"] = tuple(checks.interval(f"{key}.outflow_window",
                                                             list(values["outflow_window"])))
        s = cls(**values)
        checks.number(f"{key}.occupancy_radius_d", s.occupancy_radius_d, lo=0.5, hi=2.0, lo_open=True)
        checks.positive_int(f"{key}.n_layers", s.n_layers)
        checks.positive(f"{key}.tail_time", s.tail_time)
        checks.number(f"{key}.drain_fraction", s.drain_fraction, lo=0.5, hi=1.0, lo_open=True)
        checks.number(f"{key}.drain_margin", s.drain_margin, lo=0.0, hi=0.2, lo_open=True)
        lo, hi = s.outflow_window
        if not 0.0 <= lo < hi <= 1.0:
            raise ConfigError(f"config value {key}.outflow_window={list(s.outflow_window)} is invalid: "
                              "needs 0 <= lo < hi <= 1 (shares of the discharged material)")
        checks.number(f"{key}.mass_flow_threshold", s.mass_flow_threshold, lo=-1.0, hi=1.0)
        return s

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["outflow_window"] = list(self.outflow_window)
        return d


def metric_times(horizon: float, interval: float) -> np.ndarray:
    """Snapshot times 0, interval, ..., horizon (rounded like the stored times, so they compare equal)."""
    return np.round(np.arange(int(round(horizon / interval)) + 1) * interval, 9)


def occupied_counts(occupancy: np.ndarray) -> np.ndarray:
    """Soft count per snapshot: the sum of occupancy probabilities (0/1 fields give the plain count)."""
    return np.asarray(occupancy, dtype=np.float64).sum(axis=1)


def final_level(times: np.ndarray, counts: np.ndarray, tail_time: float) -> float:
    """Mean count over the last `tail_time` seconds (at least the last snapshot)."""
    tail = times >= times[-1] - tail_time - 1e-9
    return float(np.mean(counts[tail]))


def residual_fraction(times: np.ndarray, counts: np.ndarray, n0: int, tail_time: float) -> float:
    return final_level(times, counts, tail_time) / n0


def crossing_time(times: np.ndarray, counts: np.ndarray, level: float) -> float:
    """First time the count falls to `level`, linearly interpolated between snapshots (NaN if never)."""
    below = np.flatnonzero(counts <= level)
    if len(below) == 0:
        return float("nan")
    k = below[0]
    if k == 0:
        return float(times[0])
    c0, c1 = counts[k - 1], counts[k]
    frac = (c0 - level) / (c0 - c1) if c0 != c1 else 1.0
    return float(times[k - 1] + frac * (times[k] - times[k - 1]))


def discharged(times: np.ndarray, counts: np.ndarray, tail_time: float) -> float:
    """Material that leaves over the time range: start count - final level."""
    return float(counts[0] - final_level(times, counts, tail_time))


def drainage_t95(times: np.ndarray, counts: np.ndarray, tail_time: float, fraction: float = 0.95) -> float:
    """Time when `fraction` of the discharged material has left (0 when nothing leaves)."""
    d = discharged(times, counts, tail_time)
    if d <= 0:
        return 0.0
    return crossing_time(times, counts, counts[0] - fraction * d)


def drainage_time(times: np.ndarray, counts: np.ndarray, n0: int, tail_time: float, margin: float = 0.01) -> float:
    """Secondary rule: first time the count is within `margin` * N0 of the final level."""
    done = np.flatnonzero(counts - final_level(times, counts, tail_time) <= margin * n0)
    return float(times[done[0]])


def outflow_rate(times: np.ndarray, counts: np.ndarray, n0: int, tail_time: float,
                 window: tuple[float, float] = (0.2, 0.7)) -> float:
    """Mean discharge rate [N0 / s] while the `window` shares of the discharged material leave."""
    d = discharged(times, counts, tail_time)
    if d <= 0:
        return 0.0
    levels = [counts[0] - w * d for w in window]
    t_a, t_b = (crossing_time(times, counts, lv) for lv in levels)
    if not t_b > t_a:
        return float("nan")
    return float((levels[0] - levels[1]) / (t_b - t_a) / n0)


def layer_edges(initial_z: np.ndarray, n_layers: int = 8) -> np.ndarray:
    return np.linspace(float(np.min(initial_z)), float(np.max(initial_z)), n_layers + 1)


def layer_of(transport_z: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Layer index (0 = bottom) of the initial height `transport_z` (NaN counts as the bottom layer)."""
    n_layers = len(edges) - 1
    return np.clip(np.searchsorted(edges, np.nan_to_num(transport_z, nan=edges[0]), side="right") - 1,
                   0, n_layers - 1)


def layer_stripes(occupancy: np.ndarray, transport_z: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(T, n_layers) soft count of the material at the query points that started in each height layer."""
    layer = layer_of(transport_z, edges)
    weight = np.asarray(occupancy, dtype=np.float64)
    out = np.zeros((weight.shape[0], len(edges) - 1))
    for k in range(out.shape[1]):
        out[:, k] = np.where(layer == k, weight, 0.0).sum(axis=1)
    return out


def mass_flow_index(times: np.ndarray, stripes: np.ndarray) -> float:
    """Rank correlation of layer height with its half-depletion time (never depleted = last)."""
    initial = stripes[0]
    half_times = np.array([crossing_time(times, stripes[:, k], 0.5 * initial[k]) if initial[k] > 0
                           else np.nan for k in range(stripes.shape[1])])
    half_times = np.where(np.isnan(half_times), np.inf, half_times)
    if np.all(half_times == half_times[0]):
        return float("nan")
    ranks = np.column_stack([average_ranks(np.arange(len(half_times))), average_ranks(half_times)])
    return float(np.corrcoef(ranks, rowvar=False)[1, 0])


def average_ranks(values: np.ndarray) -> np.ndarray:
    """Ranks 1..n, ties sharing their mean rank: Spearman's ranks without importing scipy.stats (about a second
    of a what-if's time); `mass_flow_index` from them equals scipy.stats.spearmanr's bit for bit (tested)."""
    a = np.asarray(values, dtype=np.float64)
    order = np.argsort(a, kind="mergesort")
    s = a[order]
    new = np.r_[True, s[1:] != s[:-1]]
    dense = np.cumsum(new)[np.argsort(order, kind="mergesort")]
    bounds = np.r_[np.nonzero(new)[0], len(a)]
    return 0.5 * (bounds[dense] + bounds[dense - 1] + 1)


def flow_regime(index: float, threshold: float = 0.5) -> str:
    return "mass" if index > threshold else "funnel"


def hopper_summary(times: np.ndarray, occupancy: np.ndarray, transport_z: np.ndarray, initial_z: np.ndarray,
                   settings: HopperMetricSettings = HopperMetricSettings()) -> dict[str, float]:
    """All scalar hopper metrics of one trajectory (ground truth or prediction)."""
    n0 = occupancy.shape[1]
    counts = occupied_counts(occupancy)
    s = settings
    index = mass_flow_index(times, layer_stripes(occupancy, transport_z, layer_edges(initial_z, s.n_layers)))
    return {
        "drainage_t95": drainage_t95(times, counts, s.tail_time, s.drain_fraction),
        "drainage_time": drainage_time(times, counts, n0, s.tail_time, s.drain_margin),
        "residual_fraction": residual_fraction(times, counts, n0, s.tail_time),
        "outflow_rate": outflow_rate(times, counts, n0, s.tail_time, s.outflow_window),
        "mass_flow_index": index,
        "mass_flow": float(flow_regime(index, s.mass_flow_threshold) == "mass"),
    }
