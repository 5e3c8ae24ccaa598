"""Targets of the refilling hopper relative to a reference time t_ref (paper sec. 4.2), and the aggregation
of residence time across periodic reference resets. Pure functions of arrays.

A refilling run never ends, so "where did this material come from" and "how long has it been inside" need
a reference frame: a past time t_ref <= t.
- transport(t; t_ref): position at t_ref of the material found at time t (the draining hopper's target is
  the same with t_ref = 0, the opening). Material inserted after t_ref has no such position: it is marked
  new (NaN transport); `displacement` = x(t) - x(t_ref) for the rest.
- residence(t; t_ref): time the material has spent in the hopper since t_ref: t - max(t_ref, insertion time).
  It equals t - t_ref for all material present at t_ref and is smaller for new material, which is how a
  model that predicts residence also tells new material apart.

Aggregation: inference resets the reference every W seconds (r_0 < r_1 < ...). Within window k the model
gives residence since r_k and the position at r_k. The residence since r_0 of material at x, t is then
  A(x, t) = residence_k(x, t)                                     for material new in window k,
  A(x, t) = (t - r_k) + A(transport_k(x, t), r_k)                  otherwise,
evaluated recursively down to window 0, where A(p, r_0) = `initial(p)` (the residence already accumulated at
r_0, zero when unknown: then A is "at least"). For particles this is exact; `aggregated_residence` takes any
field query (ground truth or model), so residence times longer than one window are still reported.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from neuraldem.errors import DataError
from neuraldem.scenes.hopper.dataset.fields import nearest_particle

TIME_TOLERANCE = 1e-6  # [s] times on the snapshot grid compare equal within this


def check_reference(t: float, t_ref: float) -> None:
    if not (np.isfinite(t) and np.isfinite(t_ref)):
        raise DataError(f"reference time t_ref={t_ref} and time t={t} must be finite numbers")
    if t_ref > t + TIME_TOLERANCE:
        raise DataError(f"reference time t_ref={t_ref:g} s is after t={t:g} s: targets are relative to a past "
                        "reference; choose t_ref <= t")


@dataclass
class ReferenceTargets:
    """Per-particle targets at time t for the particles present at t (rows in the order given)."""

    transport: np.ndarray  # (n, 3) position at t_ref; NaN for new material
    displacement: np.ndarray  # (n, 3) x(t) - x(t_ref); NaN for new material
    residence: np.ndarray  # (n,) t - max(t_ref, insertion time) [s]
    new: np.ndarray  # (n,) bool: inserted after t_ref (not present at t_ref)


def particle_targets(t: float, t_ref: float, rows_t: np.ndarray, pos_t: np.ndarray, rows_ref: np.ndarray,
                     pos_ref: np.ndarray, insert_times: np.ndarray) -> ReferenceTargets:
    """Targets of the particles `rows_t` (positions `pos_t`) present at t, relative to the snapshot at t_ref
    with particles `rows_ref` (positions `pos_ref`). Rows index `insert_times` (one per particle id)."""
    check_reference(t, t_ref)
    rows_t, rows_ref = np.asarray(rows_t, dtype=np.int64), np.asarray(rows_ref, dtype=np.int64)
    if len(rows_t) != len(pos_t) or len(rows_ref) != len(pos_ref):
        raise DataError(f"particle rows and positions differ in length ({len(rows_t)} vs {len(pos_t)} at t, "
                        f"{len(rows_ref)} vs {len(pos_ref)} at t_ref)")
    tins = np.asarray(insert_times, dtype=np.float64)[rows_t]
    if not np.isfinite(tins).all():
        raise DataError("insertion times are missing (NaN) for particles present at t: refill targets need the "
                        "insertion time of every particle (/particles/insert_time)")
    order = np.argsort(rows_ref, kind="stable")
    sorted_ref = rows_ref[order]
    pos = np.searchsorted(sorted_ref, rows_t)
    found = (pos < len(sorted_ref)) & (sorted_ref[np.minimum(pos, max(len(sorted_ref) - 1, 0))] == rows_t) \
        if len(sorted_ref) else np.zeros(len(rows_t), dtype=bool)
    transport = np.full((len(rows_t), 3), np.nan)
    transport[found] = np.asarray(pos_ref)[order[pos[found]]]
    late = found & (tins > t_ref + TIME_TOLERANCE)
    if late.any():
        raise DataError(f"{int(late.sum())} particle(s) present at t_ref={t_ref:g} s have a later insertion time: "
                        "insertion times and snapshots disagree")
    residence = t - np.maximum(t_ref, tins)
    return ReferenceTargets(transport=transport, displacement=np.asarray(pos_t) - transport,
                            residence=residence, new=~found)


@dataclass
class ReferenceFields:
    """Fields at query points at time t, relative to t_ref."""

    occupied: np.ndarray  # (Q,) bool
    transport: np.ndarray  # (Q, 3) position at t_ref of the material found there; NaN if unoccupied or new
    residence: np.ndarray  # (Q,) seconds in the hopper since t_ref; NaN if unoccupied
    new: np.ndarray  # (Q,) bool: occupied by material inserted after t_ref


def reference_fields_at(points: np.ndarray, t: float, t_ref: float, rows_t: np.ndarray, pos_t: np.ndarray,
                        rows_ref: np.ndarray, pos_ref: np.ndarray, insert_times: np.ndarray,
                        radius: float) -> ReferenceFields:
    """The targets carried to query points by the nearest particle centre within `radius` (as the draining
    hopper's fields)."""
    targets = particle_targets(t, t_ref, rows_t, pos_t, rows_ref, pos_ref, insert_times)
    occupied, src = nearest_particle(np.asarray(points, dtype=np.float64), np.asarray(pos_t), radius)
    q = len(points)
    transport, residence, new = np.full((q, 3), np.nan), np.full(q, np.nan), np.zeros(q, dtype=bool)
    transport[occupied] = targets.transport[src]
    residence[occupied] = targets.residence[src]
    new[occupied] = targets.new[src]
    return ReferenceFields(occupied=occupied, transport=transport, residence=residence, new=new)


def reset_times(t_start: float, t_end: float, window: float) -> np.ndarray:
    """Reference times r_0 = t_start, r_0 + window, ... before t_end (the resets of an inference run)."""
    if not window > 0:
        raise DataError(f"reset window={window} must be > 0 s")
    if t_end < t_start:
        raise DataError(f"t_end={t_end} is before t_start={t_start}")
    n = int(np.floor((t_end - t_start) / window + TIME_TOLERANCE))
    return t_start + window * np.arange(max(n, 0) + 1)


def window_of(resets: np.ndarray, t: float) -> int:
    """The window that holds t: the last reset at or before t."""
    k = int(np.searchsorted(resets, t + TIME_TOLERANCE, side="right")) - 1
    if k < 0:
        raise DataError(f"t={t:g} s is before the first reference time {resets[0]:g} s")
    return k


# query(k, t, points) -> (residence since resets[k] (Q,), position at resets[k] (Q, 3)); NaN where unoccupied
FieldQuery = Callable[[int, float, np.ndarray], tuple[np.ndarray, np.ndarray]]


def aggregated_residence(query: FieldQuery, resets: np.ndarray, t: float, points: np.ndarray,
                         initial: Callable[[np.ndarray], np.ndarray] | None = None, new_tolerance: float = 1e-3,
                         window: int | None = None) -> np.ndarray:
    """Residence since resets[0] (+ `initial`) of the material at `points` at time t, aggregated across the
    resets (module docstring). Material counts as new in window k when its residence is shorter than
    t - r_k by more than `new_tolerance` [s], or when it has no finite reference position. NaN where
    unoccupied, or where the reference position found no material in the window before."""
    resets = np.asarray(resets, dtype=np.float64)
    if np.any(np.diff(resets) <= 0):
        raise DataError(f"reset times must increase, got {resets.tolist()}")
    k = window_of(resets, t) if window is None else window
    check_reference(t, float(resets[k]))
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    residence, ref = query(k, t, points)
    out = np.array(residence, dtype=np.float64)
    since = t - resets[k]
    old = np.isfinite(out) & (out >= since - new_tolerance) & np.isfinite(ref).all(axis=1)
    if not old.any():
        return out
    if k == 0:
        before = np.zeros(int(old.sum())) if initial is None else np.asarray(initial(ref[old]), dtype=np.float64)
    else:  # the material's residence at the reset, from the window that ended there
        before = aggregated_residence(query, resets, float(resets[k]), ref[old], initial, new_tolerance,
                                      window=k - 1)
    out[old] = since + before
    return out


def particle_query(resets: np.ndarray, times: np.ndarray, frames: Callable[[int], tuple[np.ndarray, np.ndarray]],
                   insert_times: np.ndarray, radius: float) -> FieldQuery:
    """A FieldQuery from particle data (ground truth): `frames(k)` gives (rows, positions) of snapshot k,
    `times` the snapshot times; resets and query times must lie on the snapshot grid."""
    times = np.asarray(times, dtype=np.float64)

    def snap(t: float) -> int:
        k = int(np.argmin(np.abs(times - t)))
        if abs(times[k] - t) > TIME_TOLERANCE:
            raise DataError(f"no snapshot at t = {t:g} s: ground-truth queries need times on the snapshot grid")
        return k

    def query(k: int, t: float, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rows_t, pos_t = frames(snap(t))
        rows_r, pos_r = frames(snap(float(resets[k])))
        f = reference_fields_at(points, t, float(resets[k]), rows_t, pos_t, rows_r, pos_r, insert_times, radius)
        return f.residence, f.transport

    return query
