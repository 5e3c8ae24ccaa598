"""The draining hopper in LIGGGHTS: geometry, input file, one run, and its raw trajectory.

Stages of a run: fill the closed hopper (insert/pack), settle; open the outlet at t = 0 (the plate mesh
leaves the wall fix); snapshots every `snapshot_interval`; particles crossing a sink disk below the outlet
are counted with their exit time and deleted; stop when empty, when nothing left for `stall_time`, or at
`max_time`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np

from neuraldem.config import checks
from neuraldem.errors import ConfigError, DataError
from neuraldem.sim import liggghts
from neuraldem.sim.dump import read_dump, read_exit_file
from neuraldem.sim.material import Material
from neuraldem.sim.runner import SolverRun, run_liggghts
from neuraldem.sim.seeds import prime_seeds
from neuraldem.sim.stl import polyline, revolve, write_stl

STATUS_OK, STATUS_CLOGGED, STATUS_FAILED = "ok", "clogged", "failed"
TrajectoryT = TypeVar("TrajectoryT")


@dataclass(frozen=True)
class HopperScene:
    """Everything about a hopper run except the sampled parameters (alpha, mu_s, mu_r)."""

    material: Material = field(default_factory=Material)
    hopper_diameter: float = 0.20  # [m]
    outlet_diameter: float = 0.08  # [m]
    sink_depth: float = 0.05  # sink disk below the outlet plane [m]
    n_segments: int = 36  # azimuthal mesh resolution
    n_particles: int = 5000
    insertion_fraction: float = 0.30  # volume fraction of the loose insertion packing
    settle_time: float = 0.6  # [s] fill + settle with the outlet closed
    snapshot_interval: float = 0.05  # [s]
    stall_time: float = 0.5  # [s] stop when the count is unchanged this long
    max_time: float = 15.0  # [s] after opening
    timeout_s: float = 3600.0  # wall-clock limit for one solver run

    @classmethod
    def from_config(cls, cfg: Any, key: str) -> HopperScene:
        values = dict(cfg)
        mat = Material.from_config(values.pop("material", {}), f"{key}.material")
        checks.known_keys(key, values, cls.__dataclass_fields__)
        scene = cls(material=mat, **values)
        scene.validate(key)
        return scene

    def validate(self, key: str) -> None:
        d = self.material.diameter
        checks.positive(f"{key}.hopper_diameter", self.hopper_diameter)
        checks.number(f"{key}.outlet_diameter", self.outlet_diameter, lo=2 * d, hi=self.hopper_diameter,
                      hi_open=True)
        checks.positive(f"{key}.sink_depth", self.sink_depth)
        checks.positive_int(f"{key}.n_segments", self.n_segments)
        checks.positive_int(f"{key}.n_particles", self.n_particles)
        checks.number(f"{key}.insertion_fraction", self.insertion_fraction, lo=0.05, hi=0.45)
        checks.positive(f"{key}.settle_time", self.settle_time)
        checks.positive(f"{key}.snapshot_interval", self.snapshot_interval)
        checks.positive(f"{key}.stall_time", self.stall_time)
        checks.positive(f"{key}.max_time", self.max_time)
        checks.positive(f"{key}.timeout_s", self.timeout_s)
        if not checks.is_multiple(self.snapshot_interval, self.material.dt):
            raise ConfigError(f"{key}.snapshot_interval={self.snapshot_interval} must be a multiple of "
                              f"{key}.material.dt={self.material.dt}")
        if not checks.is_multiple(self.stall_time, self.snapshot_interval):
            raise ConfigError(f"{key}.stall_time={self.stall_time} must be a multiple of "
                              f"{key}.snapshot_interval={self.snapshot_interval}")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class HopperGeometry:
    """Derived sizes for one cone angle. Origin at the outlet centre, z up, outlet plane z = 0."""

    radius: float
    outlet_radius: float
    cone_height: float  # (R - r_o) tan(alpha); 0 for a flat bottom
    wall_height: float  # top of the cylinder, tall enough for the loose insertion packing
    sink_z: float

    @classmethod
    def for_angle(cls, scene: HopperScene, alpha_deg: float) -> HopperGeometry:
        d = scene.material.diameter
        R, ro = scene.hopper_diameter / 2, scene.outlet_diameter / 2
        hc = (R - ro) * math.tan(math.radians(alpha_deg))
        r_ins = R - 0.6 * d
        v_particles = scene.n_particles * math.pi / 6 * d**3
        # insert/pack with all_in: centres must lie a radius inside the fill region
        h_fill = v_particles / scene.insertion_fraction / (math.pi * (r_ins - d / 2) ** 2) + d
        return cls(radius=R, outlet_radius=ro, cone_height=hc, wall_height=hc + h_fill + 2.5 * d,
                   sink_z=-scene.sink_depth)

    @classmethod
    def from_attrs(cls, attrs: Mapping[str, Any]) -> HopperGeometry:
        """From stored attributes (a dataset file's /geometry): every field as a float, other keys ignored."""
        return cls(**{k: float(attrs[k]) for k in cls.__dataclass_fields__})

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) corners of the box the particles live in: the cylinder's square, sink plane to wall top."""
        return (np.array([-self.radius, -self.radius, self.sink_z]),
                np.array([self.radius, self.radius, self.wall_height]))

    def write_meshes(self, folder: Path, n_segments: int) -> None:
        edge = 2 * math.pi * self.radius / n_segments
        profile = polyline((self.outlet_radius, 0.0), (self.radius, self.cone_height), edge)
        profile += polyline((self.radius, self.cone_height), (self.radius, self.wall_height), edge)[1:]
        write_stl(folder / "wall.stl", revolve(profile, n_segments), "wall")
        write_stl(folder / "plate.stl", revolve([(0.0, 0.0), (self.outlet_radius, 0.0)], n_segments), "plate")
        write_stl(folder / "sink.stl", revolve([(0.0, self.sink_z), (self.radius, self.sink_z)], n_segments),
                  "sink")


def settle_steps(scene: HopperScene) -> int:
    """Steps of the fill + settle stage: the opening step, a multiple of the dump step."""
    n_snap = round(scene.snapshot_interval / scene.material.dt)
    return math.ceil(scene.settle_time / scene.snapshot_interval) * n_snap


def fill_and_settle_input(scene: HopperScene, geom: HopperGeometry, material: Material, seeds: list[int],
                          title: str, before_fill: str = "") -> str:
    """The input up to the opening of the outlet, shared by the draining and the refilling hopper: box,
    material, meshes, the loose fill (insert/pack) and settling with the plate closed. `before_fill` goes
    in just before the fill (e.g. per-atom properties the fill particles must get)."""
    d = material.diameter
    half = geom.radius + 0.01
    n_settle = settle_steps(scene)
    r_ins = geom.radius - 0.6 * d
    return f"""# neuraldem {title} (generated; all values from the dataset's scene config)
{liggghts.preamble()}
region domain block {-half} {half} {-half} {half} {geom.sink_z - 0.02} {geom.wall_height + 0.02} units box
create_box 2 domain
neighbor {0.3 * d} bin
neigh_modify delay 0
{material.liggghts_definition()}
fix gravity all gravity 9.81 vector 0.0 0.0 -1.0
fix wall all mesh/surface file wall.stl type 2 curvature_tolerant yes
fix plate all mesh/surface file plate.stl type 2
fix sink all mesh/surface/planar file sink.stl type 2
fix walls all wall/gran {material.wall_model} mesh n_meshes 2 meshes wall plate
{before_fill}
region fill cylinder z 0.0 0.0 {r_ins} {geom.cone_height + d} {geom.wall_height - d} units box
fix template all particletemplate/sphere {seeds[0]} atom_type 1 &
    density constant {material.density} radius constant {material.radius}
fix distribution all particledistribution/discrete {seeds[1]} 1 template 1.0
fix insert all insert/pack seed {seeds[2]} distributiontemplate distribution vel constant 0.0 0.0 -0.5 &
    insert_every once overlapcheck yes all_in yes particles_in_region {scene.n_particles} region fill ntry_mc 20000
fix integrate all nve/sphere
variable natoms equal atoms
thermo_style custom step time atoms ke cpu
thermo 2000
thermo_modify lost ignore norm no

run {n_settle}
unfix insert
print "NEURALDEM_INSERTED ${{natoms}}"
print "NEURALDEM_OPEN_STEP {n_settle}"
"""


def hopper_input(scene: HopperScene, geom: HopperGeometry, material: Material, seeds: list[int]) -> str:
    dt = material.dt
    n_snap = round(scene.snapshot_interval / dt)
    n_chunk = round(scene.stall_time / dt)
    n_loops = math.ceil(scene.max_time / scene.stall_time)
    return fill_and_settle_input(scene, geom, material, seeds, "draining hopper") + f"""
unfix walls
fix walls all wall/gran {material.wall_model} mesh n_meshes 1 meshes wall
fix exits all massflow/mesh mesh sink vec_side 0.0 0.0 -1.0 count once delete_atoms yes file exits.txt writeTime
dump snapshots all custom {n_snap} dump.txt id x y z vx vy vz
dump_modify snapshots format "%d %.6f %.6f %.6f %.5g %.5g %.5g" sort id
thermo_style custom step time atoms ke cpu
thermo_modify lost ignore norm no

variable previous equal ${{natoms}}
label drain
variable k loop {n_loops}
  run {n_chunk}
  variable current equal ${{natoms}}
  print "NEURALDEM_CHUNK ${{k}} ${{current}}"
  if "${{current}} == 0" then "jump SELF done"
  if "${{current}} == ${{previous}}" then "jump SELF done"
  variable previous equal ${{current}}
next k
jump SELF drain
label done
print "NEURALDEM_END"
"""


class TrajectorySize:
    """`n_particles` and `n_snapshots` of anything with per-particle `ids` and snapshot `times`: the
    trajectories and the files that store them count the same way."""

    ids: np.ndarray
    times: np.ndarray

    @property
    def n_particles(self) -> int:
        return len(self.ids)

    @property
    def n_snapshots(self) -> int:
        return len(self.times)


@dataclass
class HopperTrajectory(TrajectorySize):
    """A finished run, on the time axis t = 0 at outlet opening."""

    ids: np.ndarray  # (N0,) ids of the particles present at t = 0, sorted
    times: np.ndarray  # (T,) snapshot times
    positions: np.ndarray  # (T, N0, 3) float64, NaN where the particle has exited
    velocities: np.ndarray | None  # (T, N0, 3); None in compact copies made for training
    exit_times: np.ndarray  # (N0,) exit time at the sink, NaN if it never left
    n_inserted: int
    geometry: HopperGeometry

    def counts(self) -> np.ndarray:
        return np.isfinite(self.positions[..., 0]).sum(axis=1)


@dataclass
class RunResult(Generic[TrajectoryT]):
    """One hopper run as datagen records it: ok / clogged / failed with the reason, the solver run, the
    trajectory (None when the run failed before one could be read) and the diagnostics."""

    status: str
    reason: str
    solver: SolverRun | None
    trajectory: TrajectoryT | None
    diagnostics: dict[str, Any]


class HopperRunResult(RunResult[HopperTrajectory]):
    """A draining-hopper run."""


def trajectory_from_files(dump_path: Path, exit_path: Path | None, dt: float, open_step: int,
                          geometry: HopperGeometry, n_inserted: int | None = None,
                          drop_truncated_tail: bool = False) -> HopperTrajectory:
    """Dense arrays from a dump (+ exit file). The first frame defines the particle set (t = 0)."""
    frames = read_dump(dump_path, required=("id", "x", "y", "z", "vx", "vy", "vz"),
                       drop_truncated_tail=drop_truncated_tail)
    frames = [f for f in frames if f.step >= open_step]
    if not frames:
        raise DataError(f"{dump_path}: no frame at or after the opening step {open_step}")
    ids = np.sort(frames[0].column("id").astype(np.int64))
    T, N = len(frames), len(ids)
    pos = np.full((T, N, 3), np.nan)
    vel = np.full((T, N, 3), np.nan)
    for t, frame in enumerate(frames):
        fid = frame.column("id").astype(np.int64)
        idx = np.searchsorted(ids, fid)
        known = (idx < N) & (ids[np.minimum(idx, N - 1)] == fid)
        idx = idx[known]
        pos[t, idx] = frame.data[known][:, [frame.columns.index(c) for c in ("x", "y", "z")]]
        vel[t, idx] = frame.data[known][:, [frame.columns.index(c) for c in ("vx", "vy", "vz")]]
    # LIGGGHTS deletes atoms that crossed the sink only at the next re-neighbouring: a particle below the
    # sink plane has left, even if the dump still lists it
    crossed = pos[..., 2] < geometry.sink_z
    pos[crossed] = np.nan
    vel[crossed] = np.nan
    times = np.round((np.array([f.step for f in frames]) - open_step) * dt, 9)  # same grid as time_grid()
    exit_times = np.full(N, np.nan)
    if exit_path is not None and Path(exit_path).exists():
        eid, etime = read_exit_file(exit_path)
        idx = np.searchsorted(ids, eid)
        known = (idx < N) & (ids[np.minimum(idx, N - 1)] == eid)
        exit_times[idx[known]] = etime[known] - open_step * dt
    return HopperTrajectory(ids=ids, times=times, positions=pos, velocities=vel, exit_times=exit_times,
                            n_inserted=n_inserted if n_inserted is not None else N, geometry=geometry)


def particles_over_outlet(positions: np.ndarray, outlet_radius: float, diameter: float) -> int:
    """Particle centres (N, 3; NaN = gone) in the column just above the outlet: within 0.8 outlet radii of
    the axis, below 2 outlet radii. More than 3 there when the flow has stopped is an arch (a clog)."""
    alive = np.isfinite(positions[:, 0])
    r = np.hypot(positions[alive, 0], positions[alive, 1])
    z = positions[alive, 2]
    return int(((r < 0.8 * outlet_radius) & (z > -diameter) & (z < 2 * outlet_radius)).sum())


def classify(traj: HopperTrajectory, scene: HopperScene, ended_by: str) -> tuple[str, str]:
    """ok, or clogged: flow stopped (stall) while particles still sit in the column above the outlet.

    A dead zone on a flat bottom is not a clog: it rests beside the outlet, the column above it is empty."""
    if ended_by != "stall":
        return STATUS_OK, ""
    in_column = particles_over_outlet(traj.positions[-1], traj.geometry.outlet_radius, scene.material.diameter)
    if in_column > 3:
        return STATUS_CLOGGED, f"flow stopped with {in_column} particles arching over the outlet"
    return STATUS_OK, ""


def run_hopper(scene: HopperScene, alpha: float, mu_s: float, mu_r: float, workdir: Path,
               index: int) -> HopperRunResult:
    """Run one simulation in `workdir` (created); the result says ok / clogged / failed, never raises for a
    solver failure (datagen records it and goes on)."""
    from neuraldem.scenes.hopper.parameters import PARAMETERS

    checks.number("alpha", alpha, lo=PARAMETERS["alpha"].low, hi=PARAMETERS["alpha"].high)
    material = Material(**{**scene.material.as_dict(), "mu_s": mu_s, "mu_r": mu_r})
    material.validate("parameters")
    workdir.mkdir(parents=True, exist_ok=True)
    geom = HopperGeometry.for_angle(scene, alpha)
    geom.write_meshes(workdir, scene.n_segments)
    run, diag, failure, open_step = run_hopper_input(
        workdir, hopper_input(scene, geom, material, prime_seeds(index, 3)), scene,
        "either the insertion region was too small (lower insertion_fraction) or particles flew out (is dt = "
        f"{material.dt:g} s stable for this stiffness?)")
    if failure:
        return HopperRunResult(STATUS_FAILED, failure, run, None, diag)
    n_inserted = scene.n_particles  # checked by run_hopper_input
    traj = trajectory_from_files(workdir / "dump.txt", workdir / "exits.txt", material.dt, open_step, geom,
                                 n_inserted)
    counts = [n_inserted] + [int(line.split()[2]) for line in run.log.splitlines()
                             if line.startswith("NEURALDEM_CHUNK")]
    ended_by = "empty" if counts[-1] == 0 else ("stall" if len(counts) > 1 and counts[-1] == counts[-2]
                                                else "max_time")
    n_exited = int(np.isfinite(traj.exit_times).sum())
    n_lost, n_in_flight = particle_balance(n_inserted, counts[-1], n_exited, ended_by)
    diag.update(ended_by=ended_by, n_exited=n_exited, n_lost=n_lost, n_in_flight=n_in_flight,
                particle_steps=_particle_steps(run.log))
    status, reason = classify(traj, scene, ended_by)
    if diag["n_lost"] != 0:
        status, reason = STATUS_FAILED, f"{diag['n_lost']} particles left the domain without passing the sink"
    return HopperRunResult(status, reason, run, traj, diag)


def run_hopper_input(workdir: Path, text: str, scene: HopperScene,
                     underfill_hint: str) -> tuple[SolverRun, dict[str, Any], str, int]:
    """Write `text` to workdir/in.hopper, run LIGGGHTS and check the fill stage that the draining and the
    refilling hopper share: (run, diagnostics, failure, opening step). `failure` is "" when the run reached
    NEURALDEM_END with all particles inserted, else why not (`underfill_hint`: what to change when the fill fell
    short); the opening step is -1 for a run that did not end. Both callers record a failure, never raise it."""
    (workdir / "in.hopper").write_text(text)
    run = run_liggghts(workdir, "in.hopper", timeout_s=scene.timeout_s)
    diag: dict[str, Any] = {"cpu_s": run.cpu_s, "wall_s": run.wall_s, "max_rss_mb": run.max_rss_mb}
    if run.returncode != 0 or run.error_line or "NEURALDEM_END" not in run.log:
        status = "killed at the time limit" if run.returncode == -9 else f"exit status {run.returncode}"
        reason = f"{run.error_line}: {status}" if run.error_line else f"{status}, no end marker in the log"
        return run, diag, f"{reason} (see {workdir}/log.liggghts)", -1
    n_inserted = _log_int(run.log, "NEURALDEM_INSERTED")
    open_step = _log_int(run.log, "NEURALDEM_OPEN_STEP")
    failure = "" if n_inserted == scene.n_particles else \
        f"{n_inserted} of {scene.n_particles} particles in the hopper after filling: {underfill_hint}"
    return run, diag, failure, open_step


def particle_balance(n_inserted: int, final_count: int, n_exited: int, ended_by: str) -> tuple[int, int]:
    """(lost, in flight): particles that left the domain without passing the sink, and particles counted
    twice, both exited (in the exit file) and still present (LIGGGHTS deletes them only at the next
    re-neighbouring). Only a run cut off while flowing (`max_time`) can end with particles in flight; anywhere
    else a double count is as wrong as a loss."""
    balance = n_inserted - final_count - n_exited
    if balance < 0 and ended_by == "max_time":
        return 0, -balance
    return balance, 0


def _log_int(log: str, marker: str) -> int:
    for line in log.splitlines():
        if line.startswith(marker):
            return int(float(line.split()[1]))
    raise ValueError(f"marker {marker} not in the LIGGGHTS log")


def _particle_steps(log: str) -> float:
    """Sum of steps x atoms over the runs in the log ('Loop time of X on P procs for S steps with A atoms');
    A is the count at the end of each run, so this slightly under-counts a draining run."""
    total = 0.0
    for line in log.splitlines():
        if line.startswith("Loop time of"):
            parts = line.split()
            total += float(parts[8]) * float(parts[11])
    return total
