"""`neuraldem import liggghts`: bring your own LIGGGHTS hopper run into a neuraldem dataset.

Reads a text `dump custom` file with columns `id x y z vx vy vz` (plus an optional exit file written by
`fix massflow/mesh ... file F writeTime`), converts it into the dataset format (one HDF5 file per
simulation, quantised positions) and adds or replaces its record in the dataset's manifest, with the
ground-truth metrics computed exactly as for generated data. The manifest records the scene as stated here
(hopper and outlet diameter, cone height, particle diameter, timestep), so that `neuraldem evaluate
ckpt=... dataset_dir=DATASET` scores a hopper checkpoint on these runs when its scene matches (geometry and
particle size within 1 %) and names the keys that differ when not; one dataset holds one scene. The first
frame at or after open_step= is t = 0 (the moment the outlet opens); coordinates must have the outlet centre
at the origin, z up.

Example:
  neuraldem import liggghts dump=post/dump.txt exits=post/exits.txt \\
      dataset=~/neuraldem-data/datasets/my_hoppers sim_id=plant_a dt=1e-5 open_step=60000 \\
      diameter=0.004 radius=0.12 outlet_radius=0.025 cone_height=0.08 \\
      param=[alpha=45,mu_s=0.4,mu_r=0.1] macro=[theta=24.1,repose=30.2]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.cli import doc_parser, parse_assignments, report_user_errors
from neuraldem.data.integrity import command_line, dataset_lock
from neuraldem.data.manifest import MANIFEST_NAME, Manifest, SimRecord
from neuraldem.data.schema import sha256
from neuraldem.errors import ConfigError
from neuraldem.eval.checkpoints import check_import_joins
from neuraldem.scenes.hopper.dataset.datagen import stored_metrics
from neuraldem.scenes.hopper.dataset.store import write_hopper_file
from neuraldem.scenes.hopper.solver import HopperGeometry, trajectory_from_files


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = doc_parser("neuraldem.scenes.hopper.dataset.importer", __doc__)
    p.add_argument("--dump", type=Path, required=True, help="text dump custom file (id x y z vx vy vz)")
    p.add_argument("--exits", type=Path, help="massflow/mesh exit file (id time ...), optional")
    p.add_argument("--dataset", type=Path, required=True, help="dataset dir (created if new)")
    p.add_argument("--sim-id", required=True)
    p.add_argument("--dt", type=float, required=True, help="DEM timestep of the run [s]")
    p.add_argument("--open-step", type=int, default=0, help="timestep at which the outlet opened")
    p.add_argument("--diameter", type=float, required=True, help="particle diameter [m]")
    p.add_argument("--radius", type=float, required=True, help="hopper radius [m]")
    p.add_argument("--outlet-radius", type=float, required=True)
    p.add_argument("--cone-height", type=float, default=0.0)
    p.add_argument("--sink-z", type=float, default=None, help="particles below this z have left [m]")
    p.add_argument("--resolution", type=float, default=1e-5, help="stored position resolution [m]")
    p.add_argument("--param", action="append", default=[], help="NAME=VALUE (alpha, mu_s, mu_r, ...)")
    p.add_argument("--macro", action="append", default=[], help="NAME=VALUE (theta, repose, ...)")
    p.add_argument("--drop-truncated-tail", action="store_true", help="keep the complete frames of a killed run")
    return p.parse_args(argv)


def imported_scene(a: argparse.Namespace) -> dict[str, Any]:
    """What the user stated about the run's scene, under the keys a generated hopper scene uses, so that a
    checkpoint's scene can be compared with it (`eval.checkpoints.check_scene`)."""
    return {"imported": True, "position_resolution": a.resolution,
            "hopper": {"hopper_diameter": 2 * a.radius, "outlet_diameter": 2 * a.outlet_radius,
                       "cone_height": a.cone_height, "material": {"diameter": a.diameter, "dt": a.dt}}}


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    a = parse_args(argv)
    for name in ("dt", "diameter", "radius", "outlet_radius", "resolution"):
        if not getattr(a, name) > 0:
            raise ConfigError(f"{name}= must be positive, got {getattr(a, name)}")
    params = parse_assignments(a.param, "param", "alpha=30")
    macro = parse_assignments(a.macro, "macro", "theta=24")
    sink_z = a.sink_z if a.sink_z is not None else -np.inf
    geom = HopperGeometry(radius=a.radius, outlet_radius=a.outlet_radius, cone_height=a.cone_height,
                          wall_height=np.nan, sink_z=sink_z)
    traj = trajectory_from_files(a.dump, a.exits, a.dt, a.open_step, geom,
                                 drop_truncated_tail=a.drop_truncated_tail)
    traj.geometry = HopperGeometry(radius=a.radius, outlet_radius=a.outlet_radius, cone_height=a.cone_height,
                                   wall_height=float(np.nanmax(traj.positions[..., 2])), sink_z=sink_z)
    # the only writer; the dataset is checked before it changes
    with dataset_lock(a.dataset, command_line("neuraldem.scenes.hopper.dataset.importer")):
        rel = f"sims/{a.sim_id}.h5"
        scene = imported_scene(a)
        if (a.dataset / MANIFEST_NAME).exists():
            m = Manifest.load(a.dataset)
            check_import_joins(m, scene, a.dataset, "scene")
            m.scene = scene if m.scene.get("imported") else m.scene
            m.simulations = [r for r in m.simulations if r.sim_id != a.sim_id]
        else:
            m = Manifest(name=a.dataset.name, kind="hopper", scene=scene,
                         solver={"name": "LIGGGHTS", "version": "imported"}, parameters={"names": sorted(params)})
        (a.dataset / "sims").mkdir(exist_ok=True)
        write_hopper_file(a.dataset / rel, a.sim_id, traj, params, "imported", a.resolution)
        rec = SimRecord(sim_id=a.sim_id, index=len(m.simulations), params=params, macro=macro, status="ok",
                        file=rel, sha256=sha256(a.dataset / rel),
                        metrics=stored_metrics(a.dataset / rel, a.diameter),
                        diagnostics={"imported_from": str(a.dump.resolve())})
        m.simulations.append(rec)
        m.save(a.dataset)
    print(f"imported {a.sim_id}: {traj.n_particles} particles, {len(traj.times)} snapshots -> {a.dataset / rel}")
    print("metrics: " + ", ".join(f"{k}={v:.4g}" for k, v in rec.metrics.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
