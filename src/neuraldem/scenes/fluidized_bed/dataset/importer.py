"""`neuraldem import foam`: bring your own DPMFoam / MPPICFoam fluidized-bed run into a dataset.

Reads an ASCII OpenFOAM case (serial, or parallel after `reconstructPar`): the cell fields of the continuous
phase and the particle cloud of every time directory from t0= on, one snapshot every dt_ml= seconds.
The cells are put on a regular grid: a box mesh (blockMesh, any cell order) maps exactly; any other mesh is
sampled at the nearest cell centre of a grid you give (grid=, lo=, hi=). The kernel solid fraction and
mixing concentration are computed exactly as for generated data, the file is written in the dataset format
(one HDF5 file per trajectory) and its record (metrics included) is added to the dataset's manifest or
replaces the one with the same sim_id=. Coordinates: z must point up (against gravity); the mixing groups
split the box at its mid-plane in x. The manifest records the bed's scene as read (box, grid, mean particle
diameter and density, snapshot interval, field kernels), so that `neuraldem evaluate ckpt=...
dataset_dir=DATASET` rolls a bed checkpoint out on these cases when its scene matches (within 1 %, the grid
exactly) and names the keys that differ when not; one dataset holds one bed.

The scene's settings (field kernels, Lacey sample cell, snapshot interval) come from `scene=` (your scene file
or name, `neuraldem scene list`, or a generated dataset's folder), else from the dataset the run joins, else from
the options; an option given always wins. A case neuraldem ran itself (neuraldem_case.json beside its time
directories, kept by `storage.keep_raw: true`) gives its inlet velocity, its first stored time (after the
spin-up), its snapshot interval and count, so that it imports as datagen stored it.

CFDEM cases: pass the CFD folder as case= with fluid_fraction=voidfraction fluid_velocity=U, and the
particles from the LIGGGHTS dump with liggghts_dump= (columns id x y z vx vy vz, radius optional) and
dem_dt= (see docs/fluidized-bed.md).

Examples:
  neuraldem import foam case=~/runs/bed_u16 dataset=~/neuraldem-data/datasets/my_beds \\
      sim_id=bed_u16 inlet_velocity=1.6 t0=0.2 dt_ml=0.01
  neuraldem import foam case=~/runs/bed_u16 scene=my_bed dataset=~/my_beds sim_id=bed_u16 inlet_velocity=1.6
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.cli import doc_parser, parse_assignments, report_user_errors
from neuraldem.data.integrity import command_line, dataset_lock
from neuraldem.data.manifest import MANIFEST_NAME, Manifest, SimRecord
from neuraldem.data.schema import TMP_SUFFIX, sha256
from neuraldem.errors import ConfigError, DataError
from neuraldem.eval.checkpoints import check_import_joins
from neuraldem.scenes.fluidized_bed.analysis.metric_settings import BedMetricSettings
from neuraldem.scenes.fluidized_bed.dataset.datagen import FieldSettings, file_metrics
from neuraldem.scenes.fluidized_bed.dataset.store import KIND, BedFile, write_fb_file
from neuraldem.scenes.fluidized_bed.solver.case import STAMP as CASE_RECORD
from neuraldem.scenes.fluidized_bed.solver.reader import read_trajectory
from neuraldem.sim import openfoam
from neuraldem.sim.foam_reader import BoxGrid, CloudSnapshot, FoamCase, mesh_bounds, read_dict_entries, resolve


def choose_grid(case: FoamCase, a: argparse.Namespace) -> BoxGrid:
    """grid= / lo= / hi= where given; else the mesh's bounding box with one grid cell per distinct cell-centre
    coordinate along each axis (exact for a blockMesh box)."""
    bounds = mesh_bounds(case.path)
    lo = a.lo if a.lo else (bounds[0].tolist() if bounds else None)
    hi = a.hi if a.hi else (bounds[1].tolist() if bounds else None)
    if lo is None or hi is None:
        raise ConfigError(f"{case.path}: constant/polyMesh/points is not readable: give the grid box with lo= "
                          "and hi=")
    if a.grid:
        return BoxGrid(lo=tuple(lo), hi=tuple(hi), shape=tuple(a.grid))
    centres = case.cell_centres()
    span = float(np.max(np.asarray(hi) - np.asarray(lo)))
    shape = tuple(len(np.unique(np.round(centres[:, ax] / (1e-7 * span)))) for ax in range(3))
    if int(np.prod(shape)) != len(centres):
        raise ConfigError(f"{case.path}: the mesh is not a regular box grid; give the grid to sample it on with "
                          "grid=[NX,NY,NZ]")
    return BoxGrid(lo=tuple(lo), hi=tuple(hi), shape=shape)  # type: ignore[arg-type]


def imported_scene(path: Path, grid: BoxGrid, dt_ml: float, kernel_sigma: float,
                   mixing_sigma: float) -> dict[str, Any]:
    """The bed's scene as read from the case, under the keys a generated bed scene uses, so that a checkpoint's
    scene can be compared with it (`eval.checkpoints.check_scene`): box, grid, mean particle diameter and
    density, snapshot interval and the kernels of the stored fields."""
    with BedFile(path) as f:
        diameter, density = float(np.mean(f.diameters)), float(f.density)
    size = np.asarray(grid.hi) - np.asarray(grid.lo)
    return {"imported": True,
            "fluidized_bed": {"width": float(size[0]), "thickness": float(size[1]), "height": float(size[2]),
                              "cells": list(grid.shape), "diameter": diameter, "density": density,
                              "snapshot_interval": float(dt_ml)},
            "fields": {"kernel_sigma": float(kernel_sigma), "mixing_sigma": float(mixing_sigma)}}


def particle_density(case: Path, cloud: str) -> float:
    props = case / "constant" / f"{cloud}Properties"
    if resolve(props) is None:
        return float("nan")
    entries = read_dict_entries(props)
    try:
        return float(entries.get("rho0", "nan"))
    except ValueError:
        return float("nan")


def dump_cloud_reader(dump: Path, dem_dt: float, diameter: float | None):
    """CloudSnapshot per CFD time name from a LIGGGHTS text dump (CFDEM coupling runs)."""
    from neuraldem.sim.dump import read_dump

    frames = read_dump(dump, required=("id", "x", "y", "z", "vx", "vy", "vz"))
    by_time = {round(f.step * dem_dt, 9): f for f in frames}

    def read(name: str) -> CloudSnapshot:
        frame = by_time.get(round(float(name), 9))
        if frame is None:
            raise DataError(f"{dump}: no frame at t = {name} s (timestep {float(name) / dem_dt:.0f}); the dump must "
                            "be written at the CFD output times")
        ids = frame.column("id").astype(np.int64)
        order = np.argsort(ids)
        if "radius" in frame.columns:
            d = 2 * frame.column("radius")[order]
        elif diameter:
            d = np.full(len(ids), diameter)
        else:
            raise ConfigError(f"{dump} has no radius column: pass diameter=")
        xyz = np.stack([frame.column(c) for c in ("x", "y", "z")], axis=1)[order]
        vel = np.stack([frame.column(c) for c in ("vx", "vy", "vz")], axis=1)[order]
        return CloudSnapshot(orig_proc=np.zeros(len(ids), np.int64), orig_id=ids[order], positions=xyz,
                             velocities=vel, diameters=d)

    return read


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = doc_parser("neuraldem.scenes.fluidized_bed.dataset.importer", __doc__)
    p.add_argument("--case", type=Path, required=True, help="OpenFOAM case folder (serial or reconstructed)")
    p.add_argument("--dataset", type=Path, required=True, help="dataset dir (created if new)")
    p.add_argument("--sim-id", required=True)
    p.add_argument("--scene", default=None, metavar="FILE|NAME|DATASET",
                   help="the bed's scene: your scene file or name (neuraldem scene list) or a generated dataset's "
                        "folder (default: the dataset's, when it exists)")
    p.add_argument("--inlet-velocity", type=float, default=None,
                   help="superficial inlet velocity [m/s] (default: a case neuraldem ran states it)")
    p.add_argument("--t0", type=float, default=None, help="solver time of the first snapshot (default: the "
                   "first time directory with particles)")
    p.add_argument("--dt-ml", type=float, default=None, help="snapshot spacing [s] (default: spacing of the "
                   "time directories)")
    p.add_argument("--snapshots", type=int, default=None, help="at most this many snapshots")
    p.add_argument("--cloud", default="kinematicCloud", help="cloud name (lagrangian/<cloud>)")
    p.add_argument("--fluid-fraction", default="alpha.air", help="fluid fraction field (CFDEM: voidfraction)")
    p.add_argument("--fluid-velocity", default="U.air", help="fluid velocity field (CFDEM: U)")
    p.add_argument("--pressure", default="p", help="pressure field")
    p.add_argument("--grid", type=int, nargs=3, metavar=("NX", "NY", "NZ"), help="sample on this grid")
    p.add_argument("--lo", type=float, nargs=3, help="grid box corner [m] (default: mesh bounds)")
    p.add_argument("--hi", type=float, nargs=3, help="grid box corner [m] (default: mesh bounds)")
    p.add_argument("--density", type=float, default=None, help="particle density (default: rho0 of the cloud)")
    p.add_argument("--liggghts-dump", type=Path, help="CFDEM: particles from this LIGGGHTS text dump")
    p.add_argument("--dem-dt", type=float, help="CFDEM: DEM timestep of the dump [s]")
    p.add_argument("--diameter", type=float, help="CFDEM: particle diameter if the dump has no radius [m]")
    p.add_argument("--kernel-sigma", type=float, default=None,
                   help=f"[m] (default: the scene's, else {FieldSettings.kernel_sigma})")
    p.add_argument("--mixing-sigma", type=float, default=None,
                   help=f"[m] (default: the scene's, else {FieldSettings.mixing_sigma})")
    p.add_argument("--lacey-block", type=int, nargs=3, default=None,
                   help="Lacey sample cell in grid cells (default: the scene's, else "
                        f"{list(BedMetricSettings.lacey_block)})")
    p.add_argument("--param", action="append", default=[], help="NAME=VALUE recorded with the trajectory")
    return p.parse_args(argv)


def our_case(case: Path) -> dict[str, Any]:
    """What a case neuraldem ran states about itself (neuraldem_case.json): inlet velocity, first stored time,
    snapshot interval and count, density; empty for another case."""
    import json

    path = case / CASE_RECORD
    if not path.is_file():
        return {}
    rec = json.loads(path.read_text())
    scene = rec.get("scene", {})
    interval = float(scene["snapshot_interval"])
    return {"inlet_velocity": float(rec["inlet_velocity"]), "t0": float(scene["spinup_time"]), "dt_ml": interval,
            "snapshots": round(float(rec["duration"]) / interval) + 1, "density": float(scene["density"])}


def stated_settings(scene: str | None, dataset: Path) -> dict[str, Any]:
    """Field kernels, Lacey settings and snapshot interval of the stated scene: `scene=` (a scene file or name,
    or a dataset folder), else the dataset the run joins; empty when neither states them."""
    path = Path(scene).expanduser() if scene is not None else dataset
    if (path / MANIFEST_NAME).is_file():
        m = Manifest.load(path)
        if m.kind != KIND:
            raise ConfigError(f"{path} holds {m.kind} runs", "give a fluidized-bed scene or dataset")
        fields, metrics = m.scene.get("fields", {}), m.parameters.get("metrics", {})
        interval = m.scene.get(KIND, {}).get("snapshot_interval")
    elif scene is not None:
        from neuraldem.config.user import scene_config

        file, cfg = scene_config(scene)
        if cfg.get("kind") not in (None, KIND):
            raise ConfigError(f"scene={scene}: {file} is a {cfg.get('kind')} scene", "give a fluidized-bed scene")
        fields, metrics = cfg.get("fields") or {}, cfg.get("metrics") or {}
        interval = (cfg.get("scene") or {}).get("snapshot_interval")
    else:
        return {}
    out = {k: fields[k] for k in ("kernel_sigma", "mixing_sigma") if k in fields}
    out.update({k: metrics[k] for k in ("lacey_block", "lacey_min_count", "bed_quantile", "bubble_threshold")
                if k in metrics})
    if interval is not None:
        out["dt_ml"] = float(interval)
    return out


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    a = parse_args(argv)
    ours, stated = our_case(a.case), stated_settings(a.scene, a.dataset)
    for key, default in (("inlet_velocity", None), ("t0", None), ("dt_ml", None), ("snapshots", None),
                         ("density", None), ("kernel_sigma", FieldSettings.kernel_sigma),
                         ("mixing_sigma", FieldSettings.mixing_sigma),
                         ("lacey_block", list(BedMetricSettings.lacey_block))):
        if getattr(a, key) is None:  # the option, then the stated scene, then the case itself, then the default
            setattr(a, key, stated.get(key, ours.get(key, default)))
    if a.inlet_velocity is None:
        raise ConfigError("inlet_velocity= is needed: the superficial inlet velocity of the case [m/s]")
    if not a.inlet_velocity > 0:
        raise ConfigError(f"inlet_velocity= must be positive, got {a.inlet_velocity}")
    for name in ("dt_ml", "kernel_sigma", "mixing_sigma", "density", "dem_dt", "diameter"):
        v = getattr(a, name)
        if v is not None and not v > 0:
            raise ConfigError(f"{name}= must be positive, got {v}")
    if a.liggghts_dump and not a.dem_dt:
        raise ConfigError("liggghts_dump= needs dem_dt= (the DEM timestep, to turn dump steps into times)")
    case = FoamCase(a.case, cloud=a.cloud, fluid_fraction=a.fluid_fraction, fluid_velocity=a.fluid_velocity,
                    pressure=a.pressure)
    times = case.times()
    if not any(resolve(a.case / name / "C") for _, name in times) and resolve(a.case / "constant" / "C") is None:
        first = next((name for _, name in times), "0")
        run = openfoam.run_app("postProcess", a.case, ("-func", "writeCellCentres", "-time", first),
                               log_name="log.writeCellCentres")
        openfoam.require_ok(run, "postProcess -func writeCellCentres")
    reader = dump_cloud_reader(a.liggghts_dump, a.dem_dt, a.diameter) if a.liggghts_dump else None
    with_particles = [(v, n) for v, n in times if (reader is not None and v > 0) or case.has_cloud(n)]
    if not with_particles:
        raise DataError(f"{a.case}: no time directory holds particles of cloud {a.cloud!r} "
                        f"(lagrangian/{a.cloud}/positions); is cloud= right?")
    t0 = a.t0 if a.t0 is not None else with_particles[0][0]
    dt_ml = a.dt_ml
    if dt_ml is None:
        later = [v for v, _ in with_particles if v > t0 + 1e-12]
        if not later:
            raise DataError(f"{a.case}: only one time directory with particles from t0 = {t0}: nothing to import")
        dt_ml = later[0] - t0
    grid = choose_grid(case, a)
    density = a.density if a.density is not None else particle_density(a.case, a.cloud)
    traj = read_trajectory(case, grid, t0, dt_ml, a.snapshots, density=density, cloud_reader=reader)
    params = {"inlet_velocity": float(a.inlet_velocity), **parse_assignments(a.param, "param", "packing=0")}
    metrics = BedMetricSettings(**{k: stated[k] for k in ("lacey_min_count", "bed_quantile", "bubble_threshold")
                                  if k in stated}, lacey_block=tuple(a.lacey_block))  # type: ignore[arg-type]
    # the only writer; nothing changes until the checks pass
    with dataset_lock(a.dataset, command_line("neuraldem.scenes.fluidized_bed.dataset.importer")):
        (a.dataset / "sims").mkdir(exist_ok=True)
        rel = f"sims/{a.sim_id}.h5"
        staged = a.dataset / (rel + TMP_SUFFIX)  # the scene is read from the written file: checked before it counts
        try:
            write_fb_file(staged, a.sim_id, traj, params, "imported", a.kernel_sigma, a.mixing_sigma)
            scene = imported_scene(staged, grid, dt_ml, a.kernel_sigma, a.mixing_sigma)
            if (a.dataset / MANIFEST_NAME).exists():
                m = Manifest.load(a.dataset)
                if m.kind != KIND:
                    raise DataError(f"{a.dataset} holds a {m.kind!r} dataset; import fluidized beds into their "
                                    "own dataset")
                check_import_joins(m, scene, a.dataset, "bed")
                m.scene = scene
                m.simulations = [r for r in m.simulations if r.sim_id != a.sim_id]
            else:
                m = Manifest(name=a.dataset.name, kind=KIND, scene=scene,
                             solver={"name": "OpenFOAM", "version": "imported"},
                             parameters={"names": sorted(params), "metrics": {
                                 "lacey_block": list(metrics.lacey_block),
                                 "lacey_min_count": metrics.lacey_min_count,
                                 "bed_quantile": metrics.bed_quantile, "bubble_threshold": metrics.bubble_threshold}})
            os.replace(staged, a.dataset / rel)
        finally:
            staged.unlink(missing_ok=True)
        n_lost = int(np.isfinite(traj.lost_time).sum())
        rec = SimRecord(sim_id=a.sim_id, index=len(m.simulations), params=params, status="ok", file=rel,
                        sha256=sha256(a.dataset / rel), metrics=file_metrics(a.dataset / rel, metrics),
                        diagnostics={"imported_from": str(a.case.resolve()), "t0": t0,
                                     "grid_mapping": traj.grid_mapping, "n_particles": traj.n_particles,
                                     "n_lost": n_lost})
        m.simulations.append(rec)
        m.save(a.dataset)
    print(f"imported {a.sim_id}: {traj.n_particles} particles ({n_lost} lost), {len(traj.times)} snapshots every "
          f"{dt_ml:g} s on a {'x'.join(map(str, grid.shape))} grid ({traj.grid_mapping}) -> {a.dataset / rel}")
    print("metrics: " + ", ".join(f"{k}={v:.4g}" for k, v in rec.metrics.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
