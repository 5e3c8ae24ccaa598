"""One HDF5 file per hopper simulation: write (atomically) and read (validating) the trajectory.

Layout (schema 1, see docs/data-format.md):
  attrs: schema_version, kind="hopper", sim_id, params (JSON), solver, solver_version, created_utc
  /particles/ids          (N,) int64      particles present at t = 0 (outlet opening), sorted
  /particles/exit_time    (N,) float32    time the particle crossed the sink; NaN = never left
  /snapshots/time         (T,) float64    snapshot times, t = 0 at opening
  /snapshots/position     (T, N, 3) int16 quantised: x = origin + resolution * q; q = -32768: exited
  /snapshots/velocity     (T, N, 3) float16, NaN where exited (absent in compact copies, see scenes.hopper.transfer)
  /geometry               attrs: radius, outlet_radius, cone_height, wall_height, sink_z
"""

from __future__ import annotations

import json
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from neuraldem import __version__
from neuraldem.data.integrity import ValidatedH5File
from neuraldem.data.schema import SCHEMA_VERSION, atomic_write_h5
from neuraldem.errors import DataError
from neuraldem.scenes.hopper.solver import HopperGeometry, HopperTrajectory, TrajectorySize

KIND = "hopper"
MISSING = np.iinfo(np.int16).min
QMAX = np.iinfo(np.int16).max


def quantise(positions: np.ndarray, origin: np.ndarray, resolution: float) -> np.ndarray:
    q = np.rint((positions - origin) / resolution)
    present = np.isfinite(q).all(axis=-1)
    if present.any() and (q[present].min() < -QMAX or q[present].max() > QMAX):
        span = np.nanmax(positions, axis=(0, 1)) - np.nanmin(positions, axis=(0, 1))
        raise DataError(f"positions span {span.max():.3f} m, more than int16 holds at resolution {resolution} m: "
                        f"raise data.storage.position_resolution to >= {span.max() / (2 * QMAX):.2e}")
    out = np.full(positions.shape, MISSING, dtype=np.int16)
    out[present] = q[present].astype(np.int16)
    return out


def write_header(f: h5py.File, kind: str, sim_id: str, params: dict[str, float], solver_version: str,
                 **extra: Any) -> None:
    """The root attributes of every hopper-family file; `extra` (the kind's own) go before the version stamp."""
    f.attrs.update(schema_version=SCHEMA_VERSION, kind=kind, sim_id=sim_id, params=json.dumps(params),
                   solver="LIGGGHTS", solver_version=solver_version, **extra, neuraldem_version=__version__,
                   created_utc=datetime.now(UTC).isoformat(timespec="seconds"))


def write_motion(s: h5py.Group, q: np.ndarray, velocities: np.ndarray | None, chunks: tuple[int, ...],
                 **position_attrs: Any) -> None:
    """/snapshots/position (quantised, with `position_attrs`) and the optional float16 velocities, gzip'ed in
    `chunks`: one storage rule for the dense and the ragged layout."""
    dq = s.create_dataset("position", data=q, chunks=chunks, compression="gzip", compression_opts=4, shuffle=True)
    dq.attrs.update(position_attrs)
    if velocities is not None:
        s.create_dataset("velocity", data=velocities.astype(np.float16), chunks=chunks, compression="gzip",
                         compression_opts=4, shuffle=True).attrs["units"] = "m/s"


def write_hopper_file(path: Path, sim_id: str, traj: HopperTrajectory, params: dict[str, float],
                      solver_version: str, position_resolution: float, origin: np.ndarray | None = None) -> None:
    """`origin` of the quantisation grid: default the centre of the positions' bounding box (uses the int16
    range symmetrically); pass the origin of a stored file to rewrite it bit for bit."""
    pos = traj.positions
    if origin is None:
        finite = np.isfinite(pos[..., 0])
        origin = 0.5 * (np.nanmin(pos[finite], axis=0) + np.nanmax(pos[finite], axis=0))
    q = quantise(pos, origin, position_resolution)

    def fill(f: h5py.File) -> None:
        write_header(f, KIND, sim_id, params, solver_version, n_inserted=traj.n_inserted)
        g = f.create_group("particles")
        g.create_dataset("ids", data=traj.ids.astype(np.int64))
        g.create_dataset("exit_time", data=traj.exit_times.astype(np.float32))
        s = f.create_group("snapshots")
        s.create_dataset("time", data=traj.times.astype(np.float64))
        write_motion(s, q, traj.velocities, (1, pos.shape[1], 3), origin=origin, resolution=position_resolution,
                     missing=MISSING, units="m")
        f.create_group("geometry").attrs.update(asdict(traj.geometry))

    atomic_write_h5(path, fill)


class HopperFile(ValidatedH5File, TrajectorySize):
    """Validating reader. Positions come back as float64 metres with NaN for exited particles.

    Use as a context manager, or call `close()`; `load()` reads everything into a HopperTrajectory."""

    KIND = KIND

    def _read_meta(self) -> None:
        self.sim_id = str(self.f.attrs.get("sim_id", self.path.stem))
        self.params: dict[str, float] = json.loads(self.f.attrs.get("params", "{}"))
        self.ids = self._field("particles/ids")[()]
        self.exit_times = self._field("particles/exit_time")[()].astype(np.float64)
        self.times = self._field("snapshots/time")[()]
        self._pos = self._field("snapshots/position")
        self._vel = self.f.get("snapshots/velocity")  # optional: compact copies have no velocities
        self.origin = np.asarray(self._pos.attrs["origin"], dtype=np.float64)
        self.resolution = float(self._pos.attrs["resolution"])
        self.geometry = HopperGeometry.from_attrs(self._field("geometry").attrs)

    def validate(self) -> None:
        """Shapes, ordering and value ranges; the error names the file and the field."""
        T, N = self.n_snapshots, self.n_particles
        for name, ds in (("snapshots/position", self._pos), ("snapshots/velocity", self._vel)):
            if ds is not None and ds.shape != (T, N, 3):
                raise DataError(f"{self.path}: /{name} has shape {ds.shape}, expected {(T, N, 3)}")
        if self.exit_times.shape != (N,):
            raise DataError(f"{self.path}: /particles/exit_time has shape {self.exit_times.shape}, expected {(N,)}")
        if T == 0 or N == 0:
            raise DataError(f"{self.path}: empty trajectory ({T} snapshots, {N} particles)")
        if np.any(np.diff(self.times) <= 0) or abs(self.times[0]) > 1e-9:
            raise DataError(f"{self.path}: /snapshots/time must start at 0 and increase")
        if np.any(np.diff(self.ids) <= 0):
            raise DataError(f"{self.path}: /particles/ids must be sorted and unique")
        bad = np.isinf(self.exit_times) | (self.exit_times < 0)
        if bad.any():
            raise DataError(f"{self.path}: /particles/exit_time has {int(bad.sum())} negative or infinite values")
        if self._pos.dtype != np.int16:
            raise DataError(f"{self.path}: /snapshots/position has dtype {self._pos.dtype}, expected int16 "
                            "(quantised positions, docs/data-format.md)")
        if not (np.isfinite(self.origin).all() and self.resolution > 0):
            raise DataError(f"{self.path}: /snapshots/position has a broken origin/resolution attribute")
        q = self._pos[()]
        present = q[..., 0] != MISSING
        if not present[0].all():
            raise DataError(f"{self.path}: /snapshots/position: particles missing at t = 0")
        if np.any(present[1:] & ~present[:-1]):
            raise DataError(f"{self.path}: /snapshots/position: a particle reappears after it exited")
        if self._vel is not None and not np.isfinite(self._vel[()][present]).all():
            raise DataError(f"{self.path}: /snapshots/velocity has NaN/inf for particles that are present")

    def positions(self, t_index: int | slice | np.ndarray = slice(None)) -> np.ndarray:
        q = self._pos[t_index]
        out = self.origin + self.resolution * q.astype(np.float64)
        out[q[..., 0] == MISSING] = np.nan
        return out

    @property
    def has_velocities(self) -> bool:
        return self._vel is not None

    def velocities(self, t_index: int | slice | np.ndarray = slice(None)) -> np.ndarray:
        if self._vel is None:
            raise DataError(f"{self.path}: /snapshots/velocity is absent (a compact copy made for training); "
                            "use the original dataset for velocities")
        return self._vel[t_index].astype(np.float64)

    def initial_positions(self) -> np.ndarray:
        return self.positions(0)

    def load(self) -> HopperTrajectory:
        return HopperTrajectory(ids=self.ids, times=self.times, positions=self.positions(),
                                velocities=self.velocities() if self.has_velocities else None,
                                exit_times=self.exit_times,
                                n_inserted=int(self.f.attrs.get("n_inserted", self.n_particles)),
                                geometry=self.geometry)
