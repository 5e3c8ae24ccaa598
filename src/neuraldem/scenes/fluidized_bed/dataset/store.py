"""One HDF5 file per fluidized-bed trajectory: write (atomically) and read (validating).

Layout (schema 1, kind "fluidized_bed"; see docs/fluidized-bed.md). T snapshots every `dt_ml` seconds,
N particles, a regular grid of (nx, ny, nz) cells over the box:
  attrs: schema_version, kind, sim_id, params (JSON), solver, solver_version, neuraldem_version,
         created_utc, t0 (solver time of t = 0), grid_mapping (exact | nearest)
  /grid                      attrs: lo (3,), hi (3,), shape (3,) [m]; cell (i, j, k) spans lo + (i, j, k) * h
  /particles/orig_proc       (N,) int64    particle identity = (orig_proc, orig_id), sorted
  /particles/orig_id         (N,) int64
  /particles/diameter        (N,) float64  [m]; attrs: density [kg/m^3]
  /particles/label           (N,) int8     1 = group B (centre right of the mid-plane x_mid at t = 0)
  /particles/lost_time       (N,) float32  first snapshot time a particle was missing; NaN = never lost
  /snapshots/time            (T,) float64  [s], 0, dt_ml, 2 dt_ml, ...
  /snapshots/position        (T, N, 3) float32 [m]; NaN from lost_time on
  /snapshots/displacement    (T-1, N, 3) float32 [m]: position[t+1] - position[t] (next-step target)
  /snapshots/velocity        (T, N, 3) float16 [m/s] particle velocity
  /snapshots/fluid_velocity  (T, nx, ny, nz, 3) float32 [m/s] interstitial air velocity (U.air)
  /snapshots/solid_fraction  (T, nx, ny, nz) float32 kernel solid fraction
  (neuraldem.scenes.fluidized_bed.dataset.fields)
  /snapshots/mixing          (T, nx, ny, nz) float32 group-B concentration
  (neuraldem.scenes.fluidized_bed.dataset.fields)
  /snapshots/solver_fluid_fraction (T, nx, ny, nz) float32 DPMFoam's own alpha.air (cell-binned, spiky)
  /snapshots/pressure        (T, nx, ny, nz) float32 kinematic pressure p [m^2/s^2]
  /snapshots/inflow, /snapshots/outflow (T,) float64 air volume flow through bottom / top in the solver
                             step ending at each snapshot [m^3/s] (NaN where not monitored)
  /fields                    attrs: kernel_sigma, mixing_sigma [m], prior_solid_fraction, group_b_share,
                             x_mid [m]

The kernel fields are computed from the stored (float32) positions, so anyone recomputing them from the file
gets the stored values.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from neuraldem import __version__
from neuraldem.data.integrity import ValidatedH5File
from neuraldem.data.schema import SCHEMA_VERSION, atomic_write_h5
from neuraldem.errors import DataError
from neuraldem.scenes.fluidized_bed.dataset.fields import (
    DEFAULT_PRIOR,
    group_b_share,
    initial_labels,
    particle_volumes,
    solids_flux,
    trajectory_fields,
)
from neuraldem.scenes.fluidized_bed.solver.reader import BedTrajectory
from neuraldem.sim.foam_reader import BoxGrid

KIND = "fluidized_bed"
GRID_FIELDS = ("fluid_velocity", "solid_fraction", "mixing", "solver_fluid_fraction", "pressure")
SOLID_VOLUME_RTOL = 1e-4  # kernel field vs particle volume, float32 storage


def write_fb_file(path: Path, sim_id: str, traj: BedTrajectory, params: dict[str, float], solver_version: str,
                  kernel_sigma: float, mixing_sigma: float | None = None, prior: float = DEFAULT_PRIOR,
                  solver: str = "OpenFOAM DPMFoam") -> None:
    """Store a trajectory with its kernel fields (computed here from the float32 positions)."""
    pos = traj.positions.astype(np.float32)
    pos64 = pos.astype(np.float64)
    grid = traj.grid
    labels = initial_labels(pos64[0], grid)
    mixing_sigma = kernel_sigma if mixing_sigma is None else mixing_sigma
    alpha, conc = trajectory_fields(pos64, traj.diameters, labels, grid, kernel_sigma, mixing_sigma, prior)
    disp = (pos64[1:] - pos64[:-1]).astype(np.float32)
    T, N = pos.shape[:2]

    def fill(f: h5py.File) -> None:
        f.attrs.update(schema_version=SCHEMA_VERSION, kind=KIND, sim_id=sim_id, params=json.dumps(params),
                       solver=solver, solver_version=solver_version, neuraldem_version=__version__,
                       created_utc=datetime.now(UTC).isoformat(timespec="seconds"), t0=traj.t0,
                       grid_mapping=traj.grid_mapping)
        f.create_group("grid").attrs.update(lo=np.asarray(grid.lo), hi=np.asarray(grid.hi),
                                            shape=np.asarray(grid.shape, dtype=np.int64))
        g = f.create_group("particles")
        g.attrs["density"] = traj.density
        g.create_dataset("orig_proc", data=traj.orig_proc.astype(np.int64))
        g.create_dataset("orig_id", data=traj.orig_id.astype(np.int64))
        g.create_dataset("diameter", data=traj.diameters.astype(np.float64))
        g.create_dataset("label", data=labels.astype(np.int8))
        g.create_dataset("lost_time", data=traj.lost_time.astype(np.float32))
        s = f.create_group("snapshots")
        s.create_dataset("time", data=traj.times.astype(np.float64))
        opts: dict[str, Any] = {"compression": "gzip", "compression_opts": 4, "shuffle": True}
        s.create_dataset("position", data=pos, chunks=(1, N, 3), **opts)
        if T > 1:
            s.create_dataset("displacement", data=disp, chunks=(1, N, 3), **opts)
        else:
            s.create_dataset("displacement", shape=(0, N, 3), dtype=np.float32)
        s.create_dataset("velocity", data=traj.velocities.astype(np.float16), chunks=(1, N, 3), **opts)
        cells = tuple(grid.shape)
        for name, data in (("fluid_velocity", traj.fluid_velocity), ("solid_fraction", alpha), ("mixing", conc),
                           ("solver_fluid_fraction", traj.fluid_fraction), ("pressure", traj.pressure)):
            s.create_dataset(name, data=data.astype(np.float32), chunks=(1, *cells, *data.shape[4:]), **opts)
        s.create_dataset("inflow", data=traj.inflow.astype(np.float64))
        s.create_dataset("outflow", data=traj.outflow.astype(np.float64))
        f.create_group("fields").attrs.update(kernel_sigma=kernel_sigma, mixing_sigma=mixing_sigma,
                                              prior_solid_fraction=prior,
                                              group_b_share=group_b_share(labels, traj.diameters),
                                              x_mid=0.5 * (grid.lo[0] + grid.hi[0]))

    atomic_write_h5(path, fill)


class BedFile(ValidatedH5File):
    """Validating reader of one trajectory. Use as a context manager or call `close()`.

    Per-snapshot access (`positions(t)`, `solid_fraction(t)`, ..., `pair(t)` for a next-step sample) reads
    only that snapshot's chunk; `validate()` (run on open unless validate=False) checks the whole file."""

    KIND = KIND

    def _read_meta(self) -> None:
        self.sim_id = str(self.f.attrs.get("sim_id", self.path.stem))
        try:
            self.params: dict[str, float] = json.loads(self.f.attrs.get("params", "{}"))
        except json.JSONDecodeError:
            raise DataError(f"{self.path}: attribute params is not valid JSON") from None
        self.t0 = float(self.f.attrs.get("t0", np.nan))
        g = self._field("grid").attrs
        try:
            self.grid = BoxGrid(lo=tuple(float(v) for v in g["lo"]), hi=tuple(float(v) for v in g["hi"]),
                                shape=tuple(int(v) for v in g["shape"]))  # type: ignore[arg-type]
        except (KeyError, TypeError, ValueError):
            raise DataError(f"{self.path}: /grid needs attributes lo, hi (3 floats) and shape (3 ints)") from None
        self.orig_proc = self._field("particles/orig_proc")[()]
        self.orig_id = self._field("particles/orig_id")[()]
        self.diameters = self._field("particles/diameter")[()]
        self.labels = self._field("particles/label")[()]
        self.lost_time = self._field("particles/lost_time")[()].astype(np.float64)
        self.density = float(self._field("particles").attrs.get("density", np.nan))
        self.times = self._field("snapshots/time")[()]
        self._ds = {name: self._field(f"snapshots/{name}") for name in
                    ("position", "displacement", "velocity", "inflow", "outflow", *GRID_FIELDS)}
        fa = self._field("fields").attrs
        self.kernel_sigma = float(fa.get("kernel_sigma", np.nan))
        self.mixing_sigma = float(fa.get("mixing_sigma", self.kernel_sigma))
        self.prior = float(fa.get("prior_solid_fraction", np.nan))
        self.group_b_share = float(fa.get("group_b_share", np.nan))

    # ---- sizes
    @property
    def n_particles(self) -> int:
        return len(self.orig_id)

    @property
    def n_snapshots(self) -> int:
        return len(self.times)

    @property
    def dt(self) -> float:
        return float(self.times[1] - self.times[0]) if self.n_snapshots > 1 else float("nan")

    @property
    def inlet_velocity(self) -> float:
        return float(self.params.get("inlet_velocity", np.nan))

    @property
    def particle_volumes(self) -> np.ndarray:
        return particle_volumes(self.diameters)

    # ---- validation
    def _fail(self, name: str, problem: str) -> DataError:
        return DataError(f"{self.path}: /{name} {problem}")

    def validate(self) -> None:
        """Shapes, ordering and value ranges, and the kernel field against the particle volume."""
        T, N, cells = self.n_snapshots, self.n_particles, tuple(self.grid.shape)
        if T == 0 or N == 0:
            raise DataError(f"{self.path}: empty trajectory ({T} snapshots, {N} particles)")
        if min(cells) < 1 or not all(h > lo for lo, h in zip(self.grid.lo, self.grid.hi, strict=False)):
            raise self._fail("grid", f"is degenerate (lo {self.grid.lo}, hi {self.grid.hi}, shape {cells})")
        expected = {"position": (T, N, 3), "displacement": (T - 1, N, 3), "velocity": (T, N, 3), "inflow": (T,),
                    "outflow": (T,), "fluid_velocity": (T, *cells, 3)}
        for name in ("solid_fraction", "mixing", "solver_fluid_fraction", "pressure"):
            expected[name] = (T, *cells)
        for name, shape in expected.items():
            if self._ds[name].shape != shape:
                raise self._fail(f"snapshots/{name}", f"has shape {self._ds[name].shape}, expected {shape}")
        for name, arr in (("orig_proc", self.orig_proc), ("diameter", self.diameters), ("label", self.labels),
                          ("lost_time", self.lost_time)):
            if arr.shape != (N,):
                raise self._fail(f"particles/{name}", f"has shape {arr.shape}, expected {(N,)}")
        if abs(self.times[0]) > 1e-9 or np.any(np.diff(self.times) <= 0):
            raise self._fail("snapshots/time", "must start at 0 and increase")
        keys = (self.orig_proc.astype(np.int64) << 32) + self.orig_id.astype(np.int64)
        if np.any(np.diff(keys) <= 0):
            raise self._fail("particles/orig_id", "(with orig_proc) must be sorted and unique")
        if not (np.all(np.isfinite(self.diameters)) and np.all(self.diameters > 0)):
            raise self._fail("particles/diameter", "must be positive")
        if not np.isin(self.labels, (0, 1)).all():
            raise self._fail("particles/label", "must be 0 or 1")
        if np.any(np.isinf(self.lost_time) | (self.lost_time < 0)):
            raise self._fail("particles/lost_time", "has negative or infinite values")
        pos = self._ds["position"][()].astype(np.float64)
        present = np.isfinite(pos).all(axis=2)
        if not present[0].all():
            raise self._fail("snapshots/position", "has particles missing at t = 0")
        expected_present = self.times[:, None] < np.nan_to_num(self.lost_time, nan=np.inf)[None, :] - 1e-9
        if np.any(present != expected_present):
            raise self._fail("snapshots/position", "disagrees with /particles/lost_time (a particle missing "
                             "before it was lost, or present after)")
        tol = 1e-6
        lo, hi = np.asarray(self.grid.lo) - tol, np.asarray(self.grid.hi) + tol
        p = pos[present]
        if np.any(p < lo) or np.any(p > hi):
            raise self._fail("snapshots/position", "has particle centres outside the grid box")
        disp = self._ds["displacement"][()].astype(np.float64)
        both = present[1:] & present[:-1]
        if T > 1 and np.nanmax(np.abs(disp[both] - (pos[1:] - pos[:-1])[both]), initial=0.0) > 1e-6:
            raise self._fail("snapshots/displacement", "is not position[t+1] - position[t]")
        vel = self._ds["velocity"][()]
        if not np.isfinite(vel[present]).all():
            raise self._fail("snapshots/velocity", "has NaN/inf for particles that are present")
        for name in GRID_FIELDS:
            if not np.isfinite(self._ds[name][()]).all():
                raise self._fail(f"snapshots/{name}", "has NaN or inf values")
        alpha = self._ds["solid_fraction"][()].astype(np.float64)
        if alpha.min() < -1e-6 or alpha.max() > 1.0:
            raise self._fail("snapshots/solid_fraction", f"outside [0, 1] ({alpha.min():.3g} .. {alpha.max():.3g})")
        mix = self._ds["mixing"][()]
        if mix.min() < -1e-6 or mix.max() > 1 + 1e-6:
            raise self._fail("snapshots/mixing", "outside [0, 1]")
        total = alpha.sum(axis=(1, 2, 3)) * self.grid.cell_volume
        particles = (present * self.particle_volumes[None, :]).sum(axis=1)
        err = np.max(np.abs(total - particles) / particles)
        if err > SOLID_VOLUME_RTOL:
            raise self._fail("snapshots/solid_fraction", f"integrates to a solid volume {err:.2e} (relative) off "
                             "the particles' volume (computed with another kernel or from other positions?)")

    # ---- per-snapshot access
    def positions(self, t: int | slice = slice(None)) -> np.ndarray:
        return self._ds["position"][t].astype(np.float64)

    def displacement(self, t: int | slice = slice(None)) -> np.ndarray:
        """Position at snapshot t + 1 minus position at t (t < T - 1)."""
        return self._ds["displacement"][t].astype(np.float64)

    def velocities(self, t: int | slice = slice(None)) -> np.ndarray:
        return self._ds["velocity"][t].astype(np.float64)

    def grid_field(self, name: str, t: int | slice = slice(None)) -> np.ndarray:
        if name not in GRID_FIELDS:
            raise DataError(f"{self.path}: no grid field {name!r}; have {list(GRID_FIELDS)}")
        return self._ds[name][t].astype(np.float64)

    def fluid_velocity(self, t: int | slice = slice(None)) -> np.ndarray:
        return self.grid_field("fluid_velocity", t)

    def solid_fraction(self, t: int | slice = slice(None)) -> np.ndarray:
        return self.grid_field("solid_fraction", t)

    def mixing(self, t: int | slice = slice(None)) -> np.ndarray:
        return self.grid_field("mixing", t)

    def solids_flux(self, t: int | slice = slice(None)) -> np.ndarray:
        """(nx, ny, nz, 3) kernel solids flux alpha_p u_s [m/s] of the step that ended at snapshot t (the last
        displacement deposited at the particles' positions at t; zero at t = 0), computed from the stored
        particles on first use and kept (`neuraldem.scenes.fluidized_bed.dataset.fields.solids_flux`)."""
        if isinstance(t, (int, np.integer)) and getattr(self, "_solids_flux", None) is None:  # one snapshot
            if not 0 <= t < self.n_snapshots:
                raise DataError(f"{self.path}: no snapshot {t} (has 0 .. {self.n_snapshots - 1})")
            if t == 0:
                return np.zeros((*self.grid.shape, 3))
            return solids_flux(self.positions(t), self.displacement(t - 1), self.diameters, self.grid,
                               self.kernel_sigma, self.dt)
        if getattr(self, "_solids_flux", None) is None:
            pos, disp = self.positions(), self.displacement()
            out = np.zeros((self.n_snapshots, *self.grid.shape, 3))
            for k in range(1, self.n_snapshots):
                out[k] = solids_flux(pos[k], disp[k - 1], self.diameters, self.grid, self.kernel_sigma, self.dt)
            self._solids_flux = out
        return self._solids_flux[t]

    def fluxes(self) -> tuple[np.ndarray, np.ndarray]:
        return self._ds["inflow"][()], self._ds["outflow"][()]

    def pair(self, t: int) -> dict[str, np.ndarray]:
        """One next-step training sample: the state at snapshot t and the targets at t + 1.

        state: position (N, 3), displacement_in (N, 3) (from t - 1 to t; zeros at t = 0), fluid_velocity
        (nx, ny, nz, 3), solid_fraction and mixing (nx, ny, nz); target: displacement (t -> t + 1) and the
        three grid fields at t + 1."""
        if not 0 <= t < self.n_snapshots - 1:
            raise DataError(f"{self.path}: snapshot {t} has no successor (0 <= t < {self.n_snapshots - 1})")
        disp_in = self.displacement(t - 1) if t > 0 else np.zeros((self.n_particles, 3))
        return {
            "time": np.asarray(self.times[t]), "position": self.positions(t), "displacement_in": disp_in,
            "fluid_velocity": self.fluid_velocity(t), "solid_fraction": self.solid_fraction(t),
            "mixing": self.mixing(t), "target_displacement": self.displacement(t),
            "target_fluid_velocity": self.fluid_velocity(t + 1),
            "target_solid_fraction": self.solid_fraction(t + 1), "target_mixing": self.mixing(t + 1),
        }
