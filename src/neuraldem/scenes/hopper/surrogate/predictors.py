"""Hopper fields over a whole trajectory without torch: from the DEM data itself (`DemPredictor`) or from the
field model exported to ONNX (`OnnxPredictor`), and what every predictor shares (`FieldQueries`: conditioning
scalars, query points in the trained box, extrapolation flags). The torch model's predictor is
`inference.ModelPredictor`. All answer the same question, fields at fixed query points on a time grid, so the
evaluation code cannot tell them apart: feeding the DEM predictor through it must reproduce the ground truth."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from neuraldem.data.manifest import SimRecord
from neuraldem.data.normalization import HopperNormalizer
from neuraldem.errors import DataError
from neuraldem.scenes.hopper.analysis.metrics import metric_times
from neuraldem.scenes.hopper.dataset.store import HopperFile


@dataclass
class TrajectoryFields:
    times: np.ndarray  # (T,)
    occupancy: np.ndarray  # (T, Q) probability in [0, 1] (0/1 for DEM)
    transport: np.ndarray  # (T, Q, 3) initial position [m]
    residence: np.ndarray  # (T, Q) seconds until exit


class HopperPredictor(Protocol):
    def fields(self, rec: SimRecord, times: np.ndarray, points: np.ndarray) -> TrajectoryFields: ...


time_grid = metric_times  # the time grid every hopper answer is given on


def hold_final_state(positions: np.ndarray, n_times: int) -> np.ndarray:
    """Extend a (T, N, 3) trajectory to n_times snapshots by repeating its last state."""
    if n_times <= len(positions):
        return positions[:n_times]
    pad = np.repeat(positions[-1:], n_times - len(positions), axis=0)
    return np.concatenate([positions, pad])


def snapshot_indices(stored: np.ndarray, times: np.ndarray, path: Path | str = "the file") -> np.ndarray:
    """The stored snapshot of every time of a grid (any subset of the snapshot times, e.g. every 2nd); times
    after the run ended take its last snapshot (the held final state)."""
    dt = float(stored[1] - stored[0]) if len(stored) > 1 else 1.0
    k = np.rint(np.asarray(times) / dt).astype(np.int64)
    inside = k < len(stored)
    if np.any(np.abs(stored[k[inside]] - np.asarray(times)[inside]) > 1e-6 * max(dt, 1.0)):
        raise DataError(f"{path}: the requested times are not on its snapshot grid (every {dt:g} s)")
    return np.minimum(k, len(stored) - 1)


@dataclass
class DemPredictor:
    """Ground truth as a 'prediction': fields computed from the particles of the HDF5 file."""

    dataset_dir: Path
    occupancy_radius: float
    horizon: float | None = None  # exit time given to particles that never leave; None = end of the run

    def fields(self, rec: SimRecord, times: np.ndarray, points: np.ndarray) -> TrajectoryFields:
        with HopperFile(self.dataset_dir / str(rec.file)) as f:
            pos, exits = f.positions(), f.exit_times
            pos = pos[snapshot_indices(f.times, times, f.path)]
        horizon = self.horizon if self.horizon is not None else float(times[-1])
        exits = np.where(np.isfinite(exits), exits, horizon)
        from neuraldem.scenes.hopper.dataset.fields import trajectory_fields_at  # scipy: only for DEM fields

        occ, transport, residence = trajectory_fields_at(points, times, pos, exits, self.occupancy_radius)
        return TrajectoryFields(times, occ.astype(np.float64), transport, residence)


class FieldQueries:
    """What every hopper field predictor shares, whatever runs the net: the conditioning scalars of a time grid,
    the query points normalised to the trained box (clipped and counted when slightly outside, refused when
    far), and where an answer extrapolates."""

    def __init__(self, norm: HopperNormalizer, conditioning: list[str], box_tolerance: float = 0.05):
        self.norm = norm
        self.conditioning = conditioning
        self.box_tolerance = box_tolerance  # query points this far (share of the box) outside it are clipped
        self.outside_box: dict[str, list[float]] = {}

    def scalars(self, rec: SimRecord, times: np.ndarray) -> np.ndarray:
        """(T, S) normalised conditioning scalars, one row per time."""
        return np.stack([self.norm.scalars(rec.conditioning(), self.conditioning, float(t)) for t in times])

    def extrapolation(self, rec: SimRecord) -> dict[str, list[float]]:
        """Where the answer for `rec` is an extrapolation: conditioning scalars outside the trained ranges
        ({name: [value, lo, hi]}) and query points outside the trained box ({"query_points_outside_box":
        [n outside, n points, largest distance in m]}, after `fields`)."""
        out = self.norm.outside_range(rec.conditioning(), self.conditioning)
        if self.outside_box.get(rec.sim_id, [0])[0]:
            out["query_points_outside_box"] = self.outside_box[rec.sim_id]
        return out

    def _query_points(self, rec: SimRecord, points: np.ndarray) -> np.ndarray:
        """Normalised query points; those slightly outside the trained box (a fill a few mm higher than every
        training run's) are clipped onto it and counted, those far outside are refused."""
        u = self.norm.positions(points)
        outside = ~np.all((u >= 0) & (u <= 1), axis=-1)
        if outside.any():
            far = ~np.all((u >= -self.box_tolerance) & (u <= 1 + self.box_tolerance), axis=-1)
            if far.any():
                self.norm.check_inside(points[far], f"{rec.sim_id} query points")
            clipped = np.clip(u, 0.0, 1.0)
            dist = np.linalg.norm(self.norm.positions_back(clipped) - points, axis=-1)
            self.outside_box[rec.sim_id] = [int(outside.sum()), len(points), float(dist.max())]
            u = clipped
        return u


class OnnxPredictor(FieldQueries):
    """The field model exported to ONNX (`models.onnx_runtime.OnnxNet`), answered without torch: the same
    fields as `inference.ModelPredictor` to float32 round-off (tests/scenes/hopper/test_fast_answers.py)."""

    def __init__(self, net: Any, norm: HopperNormalizer, conditioning: list[str], times_per_call: int = 16,
                 box_tolerance: float = 0.05):
        super().__init__(norm, conditioning, box_tolerance)
        self.net, self.times_per_call = net, times_per_call

    def fields(self, rec: SimRecord, times: np.ndarray, points: np.ndarray) -> TrajectoryFields:
        scalars = self.scalars(rec, times).astype(np.float32)
        q = self._query_points(rec, points).astype(np.float32)
        occ, transport, residence = [], [], []
        n = self.times_per_call
        for k in range(0, len(times), n):
            batch = scalars[k:k + n]
            out = self.net(scalars=batch, query_pos=np.broadcast_to(q, (len(batch), *q.shape)))
            occ.append(1.0 / (1.0 + np.exp(-out["occupancy"][..., 0])))
            transport.append(out["transport"])
            residence.append(out["residence"][..., 0])
        return TrajectoryFields(times, np.concatenate(occ), self.norm.positions_back(np.concatenate(transport)),
                                self.norm.time_back(np.concatenate(residence)))
