"""The hopper in refilling operation mode (paper sec. 4.2): the outlet stays open and new material is
inserted at the top as fast as it leaves, so the run can go on for as long as it is asked to.

Stages: the draining hopper's fill and settle (`fill_and_settle_input`), then the outlet opens at t = 0 and
every `refill.interval` the particles that left since the last top-up are replaced by new ones, inserted
(insert/pack, overlap-checked) in a slab at the top of the cylinder. Topping up the count every interval is
the outflow rate matched interval by interval; the fill level (particles in the hopper, i.e. above the
outlet plane, / N0) stays between N0 minus one interval's outflow and N0, and a run whose level leaves
`refill.level_band` is failed.

Bookkeeping, done by LIGGGHTS itself:
- every particle carries its insertion time in the per-atom property `tins` (the fill's particles get the
  fill time, < 0; each top-up sets its own time through insert/pack's `set_property`);
- refilled particles get new ids: LIGGGHTS numbers new atoms after the largest id present, so a frozen
  sentinel atom (type 2, in a corner outside the hopper) holds the largest id until the first top-up, and
  afterwards the newest top-up (at the top of the hopper) does. Post-processing checks that no id was used
  twice (an id exits at most once, appears in one unbroken run of snapshots, and after its insertion);
- particles crossing the sink are counted with their exit time and deleted, as in the draining hopper.
The run stops at `max_time`, or when nothing has left for `stall_time` (a stalled or clogged hopper).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.config import checks
from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes.hopper.solver import (
    STATUS_CLOGGED,
    STATUS_FAILED,
    STATUS_OK,
    HopperGeometry,
    HopperScene,
    RunResult,
    TrajectorySize,
    _log_int,
    _particle_steps,
    fill_and_settle_input,
    particles_over_outlet,
    run_hopper_input,
    settle_steps,
)
from neuraldem.sim.dump import read_dump, read_exit_file
from neuraldem.sim.material import Material
from neuraldem.sim.seeds import prime_seeds

INSERT_VELOCITY = -0.5  # [m/s] downward velocity of inserted particles (as in the fill)


@dataclass(frozen=True)
class RefillSettings:
    """How material is refilled; the run length is the scene's `max_time`."""

    interval: float = 0.05  # [s] top-up period
    level_band: tuple[float, float] = (0.8, 1.02)  # allowed particles in the hopper / N0, after the first top-up
    region_height_d: float = 5.0  # height of the insertion slab at the top of the cylinder [particle diameters]

    @classmethod
    def from_config(cls, cfg: Any, key: str) -> RefillSettings:
        values = dict(cfg)
        checks.known_keys(key, values, cls.__dataclass_fields__)
        if "level_band" in values:
            values["level_band"] = checks.interval(f"{key}.level_band", list(values["level_band"]))
        s = cls(**values)
        s.validate(key)
        return s

    def validate(self, key: str, scene: HopperScene | None = None) -> None:
        checks.positive(f"{key}.interval", self.interval)
        lo, hi = checks.interval(f"{key}.level_band", list(self.level_band))
        if not 0.0 < lo < 1.0 <= hi:
            raise ConfigError(f"config value {key}.level_band={list(self.level_band)} is invalid: needs "
                              f"0 < lo < 1 <= hi (fractions of the initial particle count; the top-up restores "
                              f"it to 1) (override it, e.g. {key}.level_band=[0.8,1.02])")
        checks.number(f"{key}.region_height_d", self.region_height_d, lo=2.0, hi=50.0)
        if scene is None:
            return
        if not checks.is_multiple(self.interval, scene.material.dt):
            raise ConfigError(f"config value {key}.interval={self.interval} is invalid: must be a multiple of "
                              f"data.scene.material.dt={scene.material.dt} (override it, e.g. {key}.interval=0.05)")
        if self.interval > scene.stall_time:
            raise ConfigError(f"config value {key}.interval={self.interval} is invalid: must be <= "
                              f"data.scene.stall_time={scene.stall_time} (a stall is measured in whole intervals)")

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["level_band"] = list(self.level_band)
        return out


def refill_region(geom: HopperGeometry, material: Material, settings: RefillSettings) -> tuple[float, float]:
    """(z_lo, z_hi) of the insertion slab: the top `region_height_d` diameters of the cylinder."""
    z_hi = geom.wall_height - material.diameter
    return z_hi - settings.region_height_d * material.diameter, z_hi


def settled_top(scene: HopperScene, geom: HopperGeometry) -> float:
    """Rough height of the settled fill's surface (packing fraction 0.55 over the cylinder cross-section,
    above the cone): the insertion slab must start above it."""
    d = scene.material.diameter
    volume = scene.n_particles * math.pi / 6 * d**3 / 0.55
    cone = math.pi / 3 * geom.cone_height * (geom.radius**2 + geom.radius * geom.outlet_radius
                                             + geom.outlet_radius**2)
    return geom.cone_height + max(volume - cone, 0.0) / (math.pi * geom.radius**2)


def n_intervals(scene: HopperScene, settings: RefillSettings) -> int:
    return math.ceil(scene.max_time / settings.interval - 1e-9)


def refill_input(scene: HopperScene, settings: RefillSettings, geom: HopperGeometry, material: Material,
                 seeds: list[int]) -> str:
    """The LIGGGHTS input. `seeds`: 3 for the fill, then one per top-up (LIGGGHTS wants distinct primes)."""
    d, dt = material.diameter, material.dt
    n_settle = settle_steps(scene)
    n_snap = round(scene.snapshot_interval / dt)
    n_int = round(settings.interval / dt)
    n_top = n_intervals(scene, settings)
    if len(seeds) < 3 + n_top:
        raise ValueError(f"refill_input needs {3 + n_top} seeds, got {len(seeds)}")
    k_stall = round(scene.stall_time / settings.interval)
    t_fill = round((1 - n_settle) * dt, 9)  # the fill is inserted on the first step
    z_lo, z_hi = refill_region(geom, material, settings)
    r_ins = geom.radius - 0.6 * d
    corner = geom.radius + 0.01 - d
    n0 = scene.n_particles
    head = fill_and_settle_input(
        scene, geom, material, seeds[:3], "refilling hopper",
        before_fill=f"fix tins all property/atom tins scalar yes no no {t_fill!r}\n")
    lines = [head, f"""
# refilled particles get new ids: a frozen sentinel holds the largest id until the first top-up
group flowing type 1
create_atoms 2 single {corner} {corner} {geom.sink_z} units box
group sentinel type 2
set group sentinel diameter {d} density {material.density}
velocity sentinel set 0.0 0.0 0.0
fix hold sentinel freeze
print "NEURALDEM_SENTINEL ${{natoms}}"

unfix walls
fix walls all wall/gran {material.wall_model} mesh n_meshes 1 meshes wall
fix exits all massflow/mesh mesh sink vec_side 0.0 0.0 -1.0 count once delete_atoms yes file exits.txt writeTime
region refill cylinder z 0.0 0.0 {r_ins} {z_lo} {z_hi} units box
region inside cylinder z 0.0 0.0 {geom.radius + d} 0.0 {geom.wall_height + d} units box
dump snapshots flowing custom {n_snap} dump.txt id x y z vx vy vz f_tins
dump_modify snapshots format "%d %.6f %.6f %.6f %.5g %.5g %.5g %.6f" sort id
thermo_style custom step time atoms ke cpu
thermo {max(n_int, 2000)}
thermo_modify lost ignore norm no
variable nflow equal count(flowing)
variable missing equal {n0}-count(flowing,inside)
variable want equal count(flowing,refill)+{n0}-count(flowing,inside)
variable ninserted equal f_top[1]
variable idle equal 0
"""]
    for j in range(n_top):
        t_j = round((j * n_int + 1) * dt, 9)  # insert/pack inserts on the first step of the run
        insert = (f"fix top flowing insert/pack seed {seeds[3 + j]} distributiontemplate distribution "
                  f"vel constant 0.0 0.0 {INSERT_VELOCITY} insert_every once overlapcheck yes all_in yes "
                  f"set_property tins {t_j!r} particles_in_region ${{want}} region refill ntry_mc 10000")
        lines.append(f"""variable start equal ${{nflow}}
variable miss0 equal ${{missing}}
variable added equal 0
if "${{miss0}} > 0" then "{insert}"
run {n_int}
if "${{miss0}} > 0" then "variable added equal ${{ninserted}}" "unfix top"
variable out equal ${{start}}+${{added}}-${{nflow}}
print "NEURALDEM_REFILL {j} ${{added}} ${{nflow}} ${{out}}"
if "${{out}} == 0" then "variable idle equal ${{idle}}+1" else "variable idle equal 0"
if "${{idle}} >= {k_stall}" then "jump SELF done"
""")
    lines.append("""label done
print "NEURALDEM_FINAL ${nflow}"
print "NEURALDEM_END"
""")
    return "".join(lines)


@dataclass
class RefillTrajectory(TrajectorySize):
    """A refilling run on the time axis t = 0 at outlet opening. The particle set changes: every particle
    present in at least one snapshot has a row in the per-particle arrays; each snapshot lists its own
    particles (a ragged layout: snapshot k holds rows offsets[k]:offsets[k+1] of the frame arrays)."""

    ids: np.ndarray  # (P,) LIGGGHTS ids, sorted
    insert_times: np.ndarray  # (P,) insertion time [s]; < 0 for the initial fill
    exit_times: np.ndarray  # (P,) exit time at the sink; NaN = still inside at the end
    times: np.ndarray  # (T,) snapshot times
    offsets: np.ndarray  # (T + 1,) int64
    index: np.ndarray  # (sum n_k,) int64 particle row of each frame entry, increasing within a snapshot
    positions: np.ndarray  # (sum n_k, 3) float64
    velocities: np.ndarray | None  # (sum n_k, 3); None in compact copies
    n_initial: int  # particles in the hopper at t = 0
    geometry: HopperGeometry

    def frame(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(particle rows, positions) of snapshot k."""
        sl = slice(int(self.offsets[k]), int(self.offsets[k + 1]))
        return self.index[sl], self.positions[sl]

    def dense_positions(self, k: int) -> np.ndarray:
        """(P, 3) positions at snapshot k, NaN for particles not in the hopper then."""
        out = np.full((self.n_particles, 3), np.nan)
        rows, pos = self.frame(k)
        out[rows] = pos
        return out

    def counts(self) -> np.ndarray:
        return np.diff(self.offsets)


class RefillRunResult(RunResult[RefillTrajectory]):
    """A refilling-hopper run."""


def refill_trajectory_from_files(dump_path: Path, exit_path: Path | None, dt: float, open_step: int,
                                 geometry: HopperGeometry, drop_truncated_tail: bool = False) -> RefillTrajectory:
    """The ragged trajectory from a dump with `id x y z vx vy vz f_tins` (+ the exit file). Checks that ids
    are never reused and that insertion times are consistent; errors name the file."""
    frames = read_dump(dump_path, required=("id", "x", "y", "z", "vx", "vy", "vz", "f_tins"),
                       drop_truncated_tail=drop_truncated_tail)
    frames = [f for f in frames if f.step >= open_step]
    if not frames:
        raise DataError(f"{dump_path}: no frame at or after the opening step {open_step}")
    times = np.round((np.array([f.step for f in frames]) - open_step) * dt, 9)
    frame_ids, frame_pos, frame_vel, frame_tins = [], [], [], []
    for frame in frames:
        fid = frame.column("id").astype(np.int64)
        pos = frame.data[:, [frame.columns.index(c) for c in ("x", "y", "z")]]
        keep = pos[:, 2] >= geometry.sink_z  # below the sink plane = left (deleted at the next re-neighbouring)
        order = np.argsort(fid[keep], kind="stable")
        frame_ids.append(fid[keep][order])
        frame_pos.append(pos[keep][order])
        frame_vel.append(frame.data[keep][:, [frame.columns.index(c) for c in ("vx", "vy", "vz")]][order])
        frame_tins.append(frame.column("f_tins")[keep][order])
    all_ids = np.concatenate(frame_ids)
    ids = np.unique(all_ids)
    index = np.searchsorted(ids, all_ids)
    tins_all = np.concatenate(frame_tins)
    insert_times = np.full(len(ids), np.nan)
    insert_times[index] = tins_all
    if np.any(np.abs(insert_times[index] - tins_all) > 1e-6):
        raise DataError(f"{dump_path}: a particle id carries two insertion times: an id was reused "
                        "(did the sentinel atom go missing?)")
    offsets = np.concatenate([[0], np.cumsum([len(f) for f in frame_ids])]).astype(np.int64)
    exit_times = np.full(len(ids), np.nan)
    if exit_path is not None and Path(exit_path).exists():
        eid, etime = read_exit_file(exit_path)
        idx = np.searchsorted(ids, eid)
        known = (idx < len(ids)) & (ids[np.minimum(idx, len(ids) - 1)] == eid)
        exit_times[idx[known]] = etime[known] - open_step * dt
    traj = RefillTrajectory(ids=ids, insert_times=insert_times, exit_times=exit_times, times=times,
                            offsets=offsets, index=index.astype(np.int64), positions=np.concatenate(frame_pos),
                            velocities=np.concatenate(frame_vel), n_initial=len(frame_ids[0]), geometry=geometry)
    problem = consistency_problem(traj, dt)
    if problem:
        raise DataError(f"{dump_path}: {problem}")
    return traj


def consistency_problem(traj: RefillTrajectory, dt: float) -> str | None:
    """What is wrong with the ids and times of a refill trajectory, or None. An id is one particle: it is
    present in one unbroken run of snapshots, not before its insertion, not after its exit."""
    counts = traj.counts()
    snap = np.repeat(np.arange(traj.n_snapshots), counts)
    first = np.full(traj.n_particles, traj.n_snapshots)
    last = np.full(traj.n_particles, -1)
    np.minimum.at(first, traj.index, snap)
    np.maximum.at(last, traj.index, snap)
    seen = np.bincount(traj.index, minlength=traj.n_particles)
    gaps = seen != last - first + 1
    if gaps.any():
        return (f"{int(gaps.sum())} particle id(s) leave and reappear (e.g. id {int(traj.ids[gaps][0])}): "
                "an id was used twice")
    tol = 2 * dt + 1e-6
    early = traj.times[first] < traj.insert_times - tol
    if early.any():
        return f"{int(early.sum())} particle(s) present before their insertion time (e.g. id {int(traj.ids[early][0])})"
    left = np.isfinite(traj.exit_times)
    if np.any(traj.exit_times[left] < traj.insert_times[left] - tol):
        return "a particle exits before it was inserted: an id was used twice"
    # a particle seen after its exit (beyond the exit file's 4-digit rounding and one dump step) is reused
    late = left & (traj.times[np.maximum(last, 0)] > traj.exit_times + 5e-4 * np.abs(traj.exit_times) + tol)
    if late.any():
        return f"{int(late.sum())} particle(s) present after their exit (e.g. id {int(traj.ids[late][0])})"
    return None


def fill_levels(traj: RefillTrajectory) -> np.ndarray:
    """(T,) fill level: particles in the hopper (centre at or above the outlet plane z = 0, not yet in the
    stream below the outlet) / particles at t = 0."""
    snap = np.repeat(np.arange(traj.n_snapshots), traj.counts())
    inside = np.bincount(snap[traj.positions[:, 2] >= 0.0], minlength=traj.n_snapshots)
    return inside / max(traj.n_initial, 1)


def run_refill(scene: HopperScene, settings: RefillSettings, alpha: float, mu_s: float, mu_r: float,
               workdir: Path, index: int) -> RefillRunResult:
    """Run one refilling simulation in `workdir` (created); like `run_hopper` it records failures instead
    of raising them."""
    checks.number("alpha", alpha, lo=0.0, hi=75.0)
    settings.validate("data.refill", scene)
    material = Material(**{**scene.material.as_dict(), "mu_s": mu_s, "mu_r": mu_r})
    material.validate("parameters")
    geom = HopperGeometry.for_angle(scene, alpha)
    z_lo, _ = refill_region(geom, material, settings)
    if z_lo < settled_top(scene, geom) + 2 * material.diameter:
        raise ConfigError(f"config value data.refill.region_height_d={settings.region_height_d} is invalid: the "
                          f"insertion slab (from z = {z_lo:.3f} m) reaches into the settled fill (top near "
                          f"{settled_top(scene, geom):.3f} m) at alpha = {alpha:g}: lower it")
    workdir.mkdir(parents=True, exist_ok=True)
    geom.write_meshes(workdir, scene.n_segments)
    seeds = prime_seeds(index, 3 + n_intervals(scene, settings))
    run, diag, failure, open_step = run_hopper_input(
        workdir, refill_input(scene, settings, geom, material, seeds), scene,
        "lower insertion_fraction, or check that dt is stable")
    if failure:
        return RefillRunResult(STATUS_FAILED, failure, run, None, diag)
    refills = [line.split()[1:] for line in run.log.splitlines() if line.startswith("NEURALDEM_REFILL ")]
    added = np.array([int(float(r[1])) for r in refills], dtype=np.int64)
    final_count = _log_int(run.log, "NEURALDEM_FINAL")
    traj = refill_trajectory_from_files(workdir / "dump.txt", workdir / "exits.txt", material.dt, open_step, geom)
    k_stall = round(scene.stall_time / settings.interval)
    outs = [int(float(r[3])) for r in refills]
    stalled = len(outs) >= k_stall and all(o == 0 for o in outs[-k_stall:])
    ended_by = "stall" if stalled else "max_time"
    n_exited = int(np.isfinite(traj.exit_times).sum())
    levels = fill_levels(traj)
    after_first = levels[traj.times >= settings.interval]
    # lost = gone from the last snapshot without an exit time, or inserted and never seen in a snapshot (the
    # count printed at the end may still hold a particle below the sink that LIGGGHTS deletes a few steps on)
    in_last = np.zeros(traj.n_particles, dtype=bool)
    in_last[traj.frame(traj.n_snapshots - 1)[0]] = True
    vanished = int(np.sum(~in_last & ~np.isfinite(traj.exit_times)))
    unseen = int(added.sum()) - int(np.sum(traj.insert_times > 0))
    diag.update(ended_by=ended_by, n_exited=n_exited, n_refilled=int(added.sum()), n_lost=vanished + unseen,
                final_count=final_count,
                level_min=float(after_first.min()) if after_first.size else float("nan"),
                level_max=float(after_first.max()) if after_first.size else float("nan"),
                particle_steps=_particle_steps(run.log))
    status, reason = STATUS_OK, ""
    if ended_by == "stall":
        last = traj.frame(traj.n_snapshots - 1)[1]
        arching = particles_over_outlet(last, geom.outlet_radius, material.diameter)
        status, reason = (STATUS_CLOGGED, f"flow stopped with {arching} particles arching over the outlet") \
            if arching > 3 else (STATUS_CLOGGED, "flow stopped (nothing left the hopper for stall_time)")
    lo, hi = settings.level_band
    if after_first.size and not (lo <= diag["level_min"] and diag["level_max"] <= hi):
        status, reason = STATUS_FAILED, (
            f"fill level left the band {list(settings.level_band)} (min {diag['level_min']:.3f}, max "
            f"{diag['level_max']:.3f}): the top-up could not keep up with the outflow; lower data.refill.interval "
            "or raise data.refill.region_height_d")
    if diag["n_lost"] != 0:
        status, reason = STATUS_FAILED, f"{diag['n_lost']} particles left the domain without passing the sink"
    return RefillRunResult(status, reason, run, traj, diag)
