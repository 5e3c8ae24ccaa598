"""A fluidized-bed run read back from its DPMFoam case: the stored snapshots as dense arrays (`BedTrajectory`),
the flux monitors, and the latest complete time directory a killed run resumes from."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neuraldem.errors import DataError
from neuraldem.sim.foam_reader import BoxGrid, CloudSnapshot, FoamCase, cells_to_grid, time_dirs


@dataclass
class BedTrajectory:
    """Stored snapshots of one run; t = 0 is the end of the spin-up (solver time `t0`)."""

    times: np.ndarray  # (T,) [s]
    t0: float  # solver time of t = 0
    orig_proc: np.ndarray  # (N,) int64, particle identity = (orig_proc, orig_id), sorted
    orig_id: np.ndarray  # (N,) int64
    diameters: np.ndarray  # (N,) [m]
    density: float  # particle density [kg/m^3]
    positions: np.ndarray  # (T, N, 3) [m]; NaN once a particle has left the domain
    velocities: np.ndarray  # (T, N, 3) [m/s]; NaN likewise
    lost_time: np.ndarray  # (N,) first snapshot time the particle was missing; NaN = never lost
    grid: BoxGrid
    fluid_velocity: np.ndarray  # (T, nx, ny, nz, 3) interstitial air velocity U.air [m/s]
    fluid_fraction: np.ndarray  # (T, nx, ny, nz) the solver's alpha.air (particle volume binned per cell)
    pressure: np.ndarray  # (T, nx, ny, nz) kinematic pressure p [m^2/s^2]
    inflow: np.ndarray  # (T,) air volume flow in through the bottom at each snapshot step [m^3/s]
    outflow: np.ndarray  # (T,) air volume flow out through the top [m^3/s]
    grid_mapping: str = "exact"  # how mesh cells were mapped onto the grid (exact / nearest)

    @property
    def n_particles(self) -> int:
        return len(self.orig_id)

    def counts(self) -> np.ndarray:
        return np.isfinite(self.positions[..., 0]).sum(axis=1)


def read_flux_monitor(case: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(times, values) of a surfaceFieldValue monitor over all restarts (later runs win on overlap)."""
    rows: dict[float, float] = {}
    base = case / "postProcessing" / name
    if not base.is_dir():
        return np.empty(0), np.empty(0)
    for _, start in time_dirs(base):
        path = base / start / "surfaceFieldValue.dat"
        if not path.is_file():
            continue
        for line in path.read_text(errors="replace").splitlines():
            parts = line.split()
            if not parts or line.startswith("#") or len(parts) < 2:
                continue
            try:
                rows[float(parts[0])] = float(parts[1])
            except ValueError:
                continue  # a line cut by a kill
    t = np.array(sorted(rows))
    return t, np.array([rows[k] for k in t])


def read_trajectory(case: FoamCase, grid: BoxGrid, t0: float, snapshot_interval: float,
                    n_snapshots: int | None = None, density: float = float("nan"),
                    cloud_reader: Callable[[str], CloudSnapshot] | None = None) -> BedTrajectory:
    """Snapshots from solver time `t0` on (every `snapshot_interval`; time directories in between are
    skipped) into dense arrays. The particles present at t0 define the particle set; particles missing
    later are lost (NaN from then on, `lost_time` set), particles that appear later are an error; an
    unreadable time directory is an error naming the file.
    `cloud_reader`: where the particles of a time directory come from (default: its lagrangian cloud)."""
    read_cloud = cloud_reader or case.cloud
    eps = 1e-6 * snapshot_interval
    names = []
    for value, name in case.times():
        k = (value - t0) / snapshot_interval
        if value >= t0 - eps and abs(k - round(k)) < 1e-4:
            names.append((round(k), value, name))
    if not names:
        raise DataError(f"{case.path}: no time directory at or after t = {t0} s")
    if names[0][0] != 0:
        raise DataError(f"{case.path}: no time directory at t0 = {t0} s (first stored one: {names[0][1]})")
    ks = [k for k, _, _ in names]
    if ks != list(range(len(ks))):
        missing = sorted(set(range(ks[-1] + 1)) - set(ks))
        raise DataError(f"{case.path}: time directories missing at t = "
                        f"{[round(t0 + k * snapshot_interval, 9) for k in missing[:5]]} s")
    if n_snapshots is not None:
        names = names[:n_snapshots]
    idx, mapping = cells_to_grid(case.cell_centres(), grid)
    first = read_cloud(names[0][2])
    keys0 = first.keys
    N, Tn = len(first), len(names)
    pos = np.full((Tn, N, 3), np.nan)
    vel = np.full((Tn, N, 3), np.nan)
    U = np.empty((Tn, *grid.shape, 3))
    alpha = np.empty((Tn, *grid.shape))
    p = np.empty((Tn, *grid.shape))
    lost = np.full(N, np.nan)
    times = []
    for t, (k, _, name) in enumerate(names):
        snap = first if t == 0 else read_cloud(name)
        U[t] = case.cell_field(name, "fluid_velocity")[idx]
        alpha[t] = case.cell_field(name, "fluid_fraction")[idx]
        p[t] = case.cell_field(name, "pressure")[idx]
        where = np.searchsorted(keys0, snap.keys)
        known = (where < N) & (keys0[np.minimum(where, N - 1)] == snap.keys)
        if not known.all():
            raise DataError(f"{case.cloud_dir(name)}: {int((~known).sum())} particle(s) that were not present "
                            f"at t0 = {t0} s appeared (an injection after the spin-up?)")
        pos[t, where] = snap.positions
        assert snap.velocities is not None
        vel[t, where] = snap.velocities
        missing = ~np.isfinite(pos[t, :, 0]) & ~np.isfinite(lost)
        lost[missing] = round(k * snapshot_interval, 9)
        times.append(round(k * snapshot_interval, 9))
    if np.any(np.isfinite(pos[:, :, 0]) & np.isfinite(lost)[None, :]
              & (np.asarray(times)[:, None] >= np.nan_to_num(lost, nan=np.inf)[None, :])):
        raise DataError(f"{case.path}: a particle reappears after it was lost")
    ft_in, f_in = read_flux_monitor(case.path, "flux_bottom")
    ft_out, f_out = read_flux_monitor(case.path, "flux_top")
    solver_times = np.array([t0 + t for t in times])
    return BedTrajectory(
        times=np.asarray(times), t0=t0, orig_proc=first.orig_proc, orig_id=first.orig_id,
        diameters=first.diameters, density=density, positions=pos, velocities=vel, lost_time=lost, grid=grid,
        fluid_velocity=U, fluid_fraction=alpha, pressure=p,
        inflow=-_at_times(ft_in, f_in, solver_times), outflow=_at_times(ft_out, f_out, solver_times),
        grid_mapping=mapping)


def _at_times(t: np.ndarray, v: np.ndarray, want: np.ndarray) -> np.ndarray:
    """Monitor values at the snapshot times (NaN where the monitor has no entry)."""
    out = np.full(len(want), np.nan)
    if len(t) == 0:
        return out
    hi = np.clip(np.searchsorted(t, want), 0, len(t) - 1)
    lo = np.clip(hi - 1, 0, len(t) - 1)
    i = np.where(np.abs(t[lo] - want) < np.abs(t[hi] - want), lo, hi)
    ok = np.abs(t[i] - want) < 1e-7 + 1e-9 * np.abs(want)
    out[ok] = v[i[ok]]
    return out


def latest_complete_time(case: FoamCase) -> str | None:
    """Delete incomplete time directories from the end (a killed run's last write); return the latest
    complete one after the initial one (None: start from scratch)."""
    for value, name in reversed(time_dirs(case.path)):
        if value <= 0:
            return None
        reason = case.check_time(name)
        if reason is None:
            return name
        shutil.rmtree(case.path / name)
    return None
