"""The hopper's auxiliary fields (paper sec. 4.2) computed from particles, at arbitrary query points.

- occupancy(x, t): is there a particle centre within `radius` of x at time t. The radius is larger than
  the particle radius so that the voids of a dense packing count as occupied.
- transport(x, t): initial position (t = 0) of the particle nearest to x (NaN where unoccupied).
- residence(x, t): time until that particle exits (NaN where unoccupied); particles that never exit within
  the simulation are given the end of the simulation as exit time ("at least until the end").

These are the training targets of the hopper surrogate and, evaluated at the initial particle positions
for every snapshot, the input of the ground-truth metrics: the same metric code scores DEM and surrogate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass
class HopperFields:
    occupied: np.ndarray  # (Q,) bool
    transport: np.ndarray  # (Q, 3) initial position of the nearest particle, NaN where unoccupied
    residence: np.ndarray  # (Q,) seconds until exit, NaN where unoccupied


def capped_exit_times(exit_times: np.ndarray, t_end: float) -> np.ndarray:
    """Exit times with 'never left' (NaN) replaced by the end of the simulation."""
    return np.where(np.isfinite(exit_times), exit_times, t_end)


def fields_at(points: np.ndarray, positions: np.ndarray, initial_positions: np.ndarray,
              exit_times: np.ndarray, t: float, t_end: float, radius: float) -> HopperFields:
    """Fields at `points` (Q, 3) from particle `positions` (N, 3; NaN = exited) at time `t`."""
    q = len(points)
    transport = np.full((q, 3), np.nan)
    residence = np.full(q, np.nan)
    occupied, src = nearest_particle(points, positions, radius)
    transport[occupied] = initial_positions[src]
    residence[occupied] = capped_exit_times(exit_times[src], t_end) - t
    return HopperFields(occupied=occupied, transport=transport, residence=residence)


def nearest_particle(points: np.ndarray, positions: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(occupied (Q,) bool, particle index (n_occupied,)): the particle (row of `positions`, NaN = absent)
    whose centre is nearest to each query point, for the points with a centre within `radius`."""
    present = np.isfinite(positions[:, 0])
    if not present.any():
        return np.zeros(len(points), dtype=bool), np.zeros(0, dtype=np.int64)
    idx_present = np.flatnonzero(present)
    dist, nn = cKDTree(positions[present]).query(points, k=1, distance_upper_bound=radius)
    occupied = np.isfinite(dist)
    return occupied, idx_present[nn[occupied]]


def trajectory_fields_at(points: np.ndarray, times: np.ndarray, positions: np.ndarray,
                         exit_times: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fields at fixed `points` for every snapshot: occupied (T, Q), transport (T, Q, 3), residence (T, Q)."""
    t_end = float(times[-1])
    initial = positions[0]
    per_t = [fields_at(points, positions[k], initial, exit_times, float(times[k]), t_end, radius)
             for k in range(len(times))]
    return (np.stack([f.occupied for f in per_t]), np.stack([f.transport for f in per_t]),
            np.stack([f.residence for f in per_t]))
