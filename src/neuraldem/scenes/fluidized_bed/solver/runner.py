"""Running one fluidized-bed trajectory in DPMFoam (`run_fluidized_bed`).

A run writes the case, runs blockMesh, writeCellCentres and DPMFoam serially, and reads every time directory
from the spin-up on into an `BedTrajectory`. It never raises for solver trouble: a crash, a time-out, NaNs, a
fluid speed beyond `max_fluid_speed` (divergence) or more lost particles than `max_lost_particles` give
status `failed` with the reason. Killed mid-run and started again, it resumes DPMFoam from the latest
complete time directory (incomplete ones are deleted first) and adds up the CPU time of all attempts.
"""

from __future__ import annotations

import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.errors import DataError, SolverError
from neuraldem.scenes.fluidized_bed.solver.attempts import record_attempt, run_cost
from neuraldem.scenes.fluidized_bed.solver.case import prepare_case
from neuraldem.scenes.fluidized_bed.solver.reader import BedTrajectory, read_trajectory
from neuraldem.scenes.fluidized_bed.solver.scene import BedScene
from neuraldem.sim import openfoam
from neuraldem.sim.foam_reader import FoamCase, time_dirs
from neuraldem.sim.openfoam import run_app

STATUS_OK, STATUS_FAILED = "ok", "failed"


@dataclass
class BedRunResult:
    status: str
    reason: str
    trajectory: BedTrajectory | None
    cost: dict[str, float] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)


def _mesh(workdir: Path, timeout_s: float) -> None:
    if not (workdir / "constant" / "polyMesh" / "owner").is_file():
        run = run_app("blockMesh", workdir, timeout_s=timeout_s)
        record_attempt(workdir, run, None)
        openfoam.require_ok(run, "blockMesh")
    if not (workdir / "0" / "C").is_file():
        run = run_app("postProcess", workdir, ("-func", "writeCellCentres", "-time", "0"),
                      log_name="log.writeCellCentres", timeout_s=timeout_s)
        record_attempt(workdir, run, None)
        openfoam.require_ok(run, "postProcess -func writeCellCentres")


_SUBCYCLES = re.compile(r"^\s*(\d+)\s+move-collide subCycles", re.MULTILINE)
_STEP = re.compile(r"^Time = ", re.MULTILINE)


def run_fluidized_bed(scene: BedScene, inlet_velocity: float, duration: float, workdir: Path,
                      seed: int) -> BedRunResult:
    """Run (or resume) one trajectory of `duration` stored seconds after the spin-up; never raises for
    solver trouble (status failed + reason), only for a missing OpenFOAM or bad settings."""
    openfoam.find_apps()
    openfoam.foam_env()
    sim_time = scene.spinup_time + duration
    timeout = scene.timeout_per_simulated_s * sim_time
    resumed, restart = prepare_case(scene, workdir, inlet_velocity, duration, seed)
    try:
        _mesh(workdir, timeout)
    except SolverError as err:
        return BedRunResult(STATUS_FAILED, str(err), None, run_cost(workdir, sim_time))
    load0 = os.getloadavg()[0]
    n_logs = len(list(workdir.glob("log.DPMFoam*")))
    run = run_app("DPMFoam", workdir, timeout_s=timeout,
                  log_name="log.DPMFoam" if n_logs == 0 else f"log.DPMFoam.{n_logs}.restart_{restart}")
    record_attempt(workdir, run, restart, (load0, os.getloadavg()[0]))
    cost = run_cost(workdir, sim_time)
    diagnostics: dict[str, Any] = {"resumed_from": restart} if resumed else {}
    log = run.log
    subcycles = [int(x) for x in _SUBCYCLES.findall(log)]
    n_steps = len(_STEP.findall(log))
    if n_steps:  # steps without the message have one move-collide cycle
        substeps = (sum(subcycles) + n_steps - len(subcycles)) / n_steps
        diagnostics["mean_collision_substeps"] = substeps
        # particle-steps of the whole run at this attempt's mean substep count (the hopper's cost unit)
        cost["particle_steps"] = scene.n_particles * round(sim_time / scene.dt) * substeps
    if run.error:
        return BedRunResult(STATUS_FAILED, f"DPMFoam: {run.error}", None, cost, diagnostics)
    result = finish(scene, FoamCase(workdir), duration, cost, diagnostics)
    if result.status == STATUS_OK:
        compress_logs(workdir)
    return result


def compress_logs(workdir: Path) -> None:
    """gzip the DPMFoam logs of a finished run (DPMFoam prints ~2.5 kB per step: 0.75 GB for 30 s)."""
    import gzip

    for log in workdir.glob("log.DPMFoam*"):
        if log.suffix == ".gz":
            continue
        with open(log, "rb") as src, gzip.open(log.with_name(log.name + ".gz"), "wb") as dst:
            shutil.copyfileobj(src, dst)
        log.unlink()


def finish(scene: BedScene, case: FoamCase, duration: float, cost: dict[str, float],
           diagnostics: dict[str, Any]) -> BedRunResult:
    """Read the finished case and classify it: ok, or failed (incomplete, diverged, particles lost)."""
    n_snap = round(duration / scene.snapshot_interval) + 1
    try:
        traj = read_trajectory(case, scene.grid, scene.spinup_time, scene.snapshot_interval, n_snap,
                               density=scene.density)
    except DataError as err:
        reason = str(err)
        if "NaN" in reason:
            reason = f"diverged: {reason}"
        return BedRunResult(STATUS_FAILED, reason, None, cost, diagnostics)
    if len(traj.times) < n_snap:
        return BedRunResult(STATUS_FAILED, f"{case.path}: only {len(traj.times)} of {n_snap} snapshots written",
                           None, cost, diagnostics)
    if traj.grid_mapping != "exact":
        return BedRunResult(STATUS_FAILED, f"{case.path}: mesh cell centres do not match the scene grid", None,
                           cost, diagnostics)
    n_lost = int(np.isfinite(traj.lost_time).sum())
    escaped = case.escaped_parcels(case.times()[-1][1])
    speed = float(np.max(np.linalg.norm(traj.fluid_velocity, axis=-1)))
    imbalance = np.abs(traj.inflow - traj.outflow) / np.maximum(np.abs(traj.inflow), 1e-30)
    diagnostics.update({
        "n_particles": traj.n_particles, "n_lost": n_lost, "escaped_parcels": escaped,
        "max_fluid_speed": speed, "max_flux_imbalance": float(np.nanmax(imbalance)) if imbalance.size else None,
        "min_solver_fluid_fraction": float(traj.fluid_fraction.min()),
    })
    if traj.n_particles != scene.n_particles:
        lost_in_spinup = scene.n_particles - traj.n_particles
        diagnostics["n_lost_in_spinup"] = lost_in_spinup
        n_lost += lost_in_spinup
    if speed > scene.max_fluid_speed:
        return BedRunResult(STATUS_FAILED, f"diverged: fluid speed {speed:.3g} m/s > max_fluid_speed "
                           f"{scene.max_fluid_speed} m/s", traj, cost, diagnostics)
    if n_lost > scene.max_lost_particles:
        first = float(np.nanmin(traj.lost_time)) if np.isfinite(traj.lost_time).any() else -scene.spinup_time
        return BedRunResult(STATUS_FAILED, f"{n_lost} particle(s) left the domain (first at t = {first:g} s; "
                           f"max_lost_particles = {scene.max_lost_particles})", traj, cost, diagnostics)
    return BedRunResult(STATUS_OK, "", traj, cost, diagnostics)


def remove_time_dirs(case: Path) -> None:
    """Free the disk after conversion: the time directories (keep 0, logs, postProcessing, system)."""
    for value, name in time_dirs(case):
        if value > 0:
            shutil.rmtree(case / name)
