"""One HDF5 file per refilling-hopper simulation: a trajectory whose particle set changes (insertions at the
top, exits at the sink). Written atomically, read with validation (docs/data-format.md, "hopper_refill").

Layout (schema 1, kind "hopper_refill"; a ragged layout: each snapshot stores only the particles present):
  attrs: schema_version, kind, sim_id, params (JSON), solver, solver_version, n_initial, refill (JSON), ...
  /particles/ids           (P,) int64    every particle present in at least one snapshot, sorted
  /particles/insert_time   (P,) float64  insertion time [s] (< 0: the initial fill); required, finite
  /particles/exit_time     (P,) float32  exit time at the sink; NaN = still inside at the end
  /snapshots/time          (T,) float64  t = 0 at outlet opening
  /snapshots/offsets       (T+1,) int64  snapshot k holds rows offsets[k]:offsets[k+1] of the row arrays
  /snapshots/index         (M,) int32    particle row (into /particles) of each row, increasing per snapshot
  /snapshots/position      (M, 3) int16  quantised like the draining hopper: x = origin + resolution * q
  /snapshots/velocity      (M, 3) float16 (absent in compact copies)
  /geometry                attrs: radius, outlet_radius, cone_height, wall_height, sink_z
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from neuraldem.data.integrity import ValidatedH5File
from neuraldem.data.schema import atomic_write_h5
from neuraldem.errors import DataError
from neuraldem.scenes.hopper.dataset.store import MISSING, quantise, write_header, write_motion
from neuraldem.scenes.hopper.solver import HopperGeometry, TrajectorySize
from neuraldem.scenes.hopper_refill.solver import RefillTrajectory, consistency_problem

KIND = "hopper_refill"
ROW_CHUNK = 65536
DT_TOLERANCE = 1e-4  # [s] one DEM step: slack of the insertion/exit consistency checks


def write_refill_file(path: Path, sim_id: str, traj: RefillTrajectory, params: dict[str, float],
                      solver_version: str, position_resolution: float, refill: dict[str, Any] | None = None,
                      origin: np.ndarray | None = None) -> None:
    pos = traj.positions
    if origin is None:
        origin = 0.5 * (pos.min(axis=0) + pos.max(axis=0))
    q = quantise(pos, np.asarray(origin, dtype=np.float64), position_resolution)
    chunk = (max(1, min(ROW_CHUNK, len(q))), 3)

    def fill(f: h5py.File) -> None:
        write_header(f, KIND, sim_id, params, solver_version, n_initial=traj.n_initial,
                     refill=json.dumps(refill or {}))
        g = f.create_group("particles")
        g.create_dataset("ids", data=traj.ids.astype(np.int64))
        g.create_dataset("insert_time", data=traj.insert_times.astype(np.float64))
        g.create_dataset("exit_time", data=traj.exit_times.astype(np.float32))
        s = f.create_group("snapshots")
        s.create_dataset("time", data=traj.times.astype(np.float64))
        s.create_dataset("offsets", data=traj.offsets.astype(np.int64))
        s.create_dataset("index", data=traj.index.astype(np.int32), chunks=(chunk[0],), compression="gzip",
                         compression_opts=4, shuffle=True)
        write_motion(s, q, traj.velocities, chunk, origin=origin, resolution=position_resolution, units="m")
        f.create_group("geometry").attrs.update(asdict(traj.geometry))

    atomic_write_h5(path, fill)


class RefillFile(ValidatedH5File, TrajectorySize):
    """Validating reader of a refill trajectory. `frame(k)` reads one snapshot (particle rows, positions in
    metres); `load()` reads everything into a RefillTrajectory."""

    KIND = KIND

    def _read_meta(self) -> None:
        self.sim_id = str(self.f.attrs.get("sim_id", self.path.stem))
        self.params: dict[str, float] = json.loads(self.f.attrs.get("params", "{}"))
        self.refill: dict[str, Any] = json.loads(self.f.attrs.get("refill", "{}"))
        self.ids = self._field("particles/ids")[()]
        if "particles/insert_time" not in self.f:
            raise DataError(f"{self.path}: field /particles/insert_time is missing: a refill trajectory needs the "
                            "insertion time of every particle; regenerate it with `neuraldem datagen "
                            "data=hopper_refill` (or write the field from the dump's f_tins column)")
        self.insert_times = self.f["particles/insert_time"][()].astype(np.float64)
        self.exit_times = self._field("particles/exit_time")[()].astype(np.float64)
        self.times = self._field("snapshots/time")[()]
        self.offsets = self._field("snapshots/offsets")[()].astype(np.int64)
        self._index = self._field("snapshots/index")
        self._pos = self._field("snapshots/position")
        self._vel = self.f.get("snapshots/velocity")
        self.origin = np.asarray(self._pos.attrs["origin"], dtype=np.float64)
        self.resolution = float(self._pos.attrs["resolution"])
        self.n_initial = int(self.f.attrs.get("n_initial", 0))
        self.geometry = HopperGeometry.from_attrs(self._field("geometry").attrs)

    def validate(self) -> None:
        """Shapes, ordering, finite values and one particle per id; errors name the file and the field."""
        T, P = self.n_snapshots, self.n_particles
        if T == 0 or P == 0:
            raise DataError(f"{self.path}: empty trajectory ({T} snapshots, {P} particles)")
        for name, arr in (("particles/insert_time", self.insert_times), ("particles/exit_time", self.exit_times)):
            if arr.shape != (P,):
                raise DataError(f"{self.path}: /{name} has shape {arr.shape}, expected {(P,)} (one per particle id)")
        if not np.isfinite(self.insert_times).all():
            raise DataError(f"{self.path}: /particles/insert_time has {int((~np.isfinite(self.insert_times)).sum())} "
                            "NaN/inf values: every particle needs its insertion time; regenerate the file")
        if np.isinf(self.exit_times).any():
            raise DataError(f"{self.path}: /particles/exit_time has infinite values (NaN = never left)")
        if np.any(np.diff(self.ids) <= 0):
            raise DataError(f"{self.path}: /particles/ids must be sorted and unique")
        if np.any(np.diff(self.times) <= 0) or abs(self.times[0]) > 1e-9:
            raise DataError(f"{self.path}: /snapshots/time must start at 0 and increase")
        M = self._index.shape[0]
        if self.offsets.shape != (T + 1,) or self.offsets[0] != 0 or self.offsets[-1] != M or np.any(
                np.diff(self.offsets) < 0):
            raise DataError(f"{self.path}: /snapshots/offsets must have {T + 1} non-decreasing entries from 0 to "
                            f"{M} (the length of /snapshots/index)")
        for name, ds in (("snapshots/position", self._pos), ("snapshots/velocity", self._vel)):
            if ds is not None and ds.shape != (M, 3):
                raise DataError(f"{self.path}: /{name} has shape {ds.shape}, expected {(M, 3)}")
        if not (np.isfinite(self.origin).all() and self.resolution > 0):
            raise DataError(f"{self.path}: /snapshots/position has a broken origin/resolution attribute")
        index = self._index[()].astype(np.int64)
        if index.size and (index.min() < 0 or index.max() >= P):
            raise DataError(f"{self.path}: /snapshots/index points outside /particles/ids (0 .. {P - 1})")
        within = np.diff(index)
        starts = self.offsets[1:-1]
        new_frame = np.zeros(max(M - 1, 0), dtype=bool)
        new_frame[starts[(starts > 0) & (starts < M)] - 1] = True
        if np.any((within <= 0) & ~new_frame):
            raise DataError(f"{self.path}: /snapshots/index must increase within each snapshot (a particle listed "
                            "twice in one snapshot?)")
        if np.any(self._pos[()][:, 0] == MISSING):
            raise DataError(f"{self.path}: /snapshots/position has missing-value entries; a ragged snapshot lists "
                            "only the particles present")
        if self._vel is not None and not np.isfinite(self._vel[()]).all():
            raise DataError(f"{self.path}: /snapshots/velocity has NaN/inf values")
        problem = consistency_problem(self._trajectory(index, velocities=False), DT_TOLERANCE)
        if problem:
            raise DataError(f"{self.path}: /particles vs /snapshots: {problem}")

    def frame(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(particle rows (n,), positions (n, 3) [m]) of snapshot k."""
        if not 0 <= k < self.n_snapshots:
            raise DataError(f"{self.path}: no snapshot {k} (has 0 .. {self.n_snapshots - 1})")
        sl = slice(int(self.offsets[k]), int(self.offsets[k + 1]))
        return (self._index[sl].astype(np.int64),
                self.origin + self.resolution * self._pos[sl].astype(np.float64))

    def snapshot_index(self, t: float, tol: float = 1e-6) -> int:
        """Index of the snapshot at time t (exactly on the grid)."""
        k = int(np.argmin(np.abs(self.times - t)))
        if abs(self.times[k] - t) > tol:
            raise DataError(f"{self.path}: no snapshot at t = {t:g} s (snapshots every "
                            f"{self.times[1] - self.times[0] if self.n_snapshots > 1 else 0:g} s up to "
                            f"{self.times[-1]:g} s)")
        return k

    @property
    def has_velocities(self) -> bool:
        return self._vel is not None

    def _trajectory(self, index: np.ndarray, velocities: bool) -> RefillTrajectory:
        pos = self.origin + self.resolution * self._pos[()].astype(np.float64)
        vel = self._vel[()].astype(np.float64) if velocities and self._vel is not None else None
        return RefillTrajectory(ids=self.ids, insert_times=self.insert_times, exit_times=self.exit_times,
                                times=self.times, offsets=self.offsets, index=index, positions=pos, velocities=vel,
                                n_initial=self.n_initial or int(self.offsets[1]), geometry=self.geometry)

    def load(self) -> RefillTrajectory:
        return self._trajectory(self._index[()].astype(np.int64), velocities=True)
