"""`neuraldem export FORMAT dataset=DATASET out=OUT`: a dataset's particle trajectories for other learned simulators.

FORMAT is `gns` (train/valid/test.npz + metadata.json: DeepMind's learning_to_simulate data as npz, read by the
PyTorch `gns` package) or `lagrangebench` (train/valid/test.h5 + metadata.json, read by LagrangeBench's
H5Dataset). DATASET is a dataset dir, or the name of one under <data dir>/datasets; OUT a new folder. The
split parts come from the dataset's manifest (split=, default the scene's first: hopper `random`, fluidized
bed `velocity`); a part without runs writes no file. Velocity and acceleration statistics in metadata.json
come from the training part only. docs/exports.md has the layouts and how to load them in those tools.

Both formats hold one fixed particle set per trajectory. A run in which particles leave (the hopper's sink,
particles DPMFoam lost) is refused unless exits= says what to do:
  truncate  keep each trajectory up to its first exit (needs 3 snapshots before it)
  hold      keep every snapshot; a particle that left stays at its last position, and exit_step_<split>.npz
            records when it left (neuraldem's reader, and the GNS baseline trained from the export, mask it)
Datasets whose particle set grows (the refilling hopper) cannot be exported.

Examples:
  neuraldem export gns dataset=hopper_small out=~/exports/hopper_gns exits=hold
  neuraldem export lagrangebench dataset=fb_small out=~/exports/fb_lb
  neuraldem train experiment=gns_export_tiny data.export_dir=~/exports/hopper_gns
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem import __version__
from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.config import checks
from neuraldem.data.manifest import Manifest, SimRecord, find_dataset, require_dataset
from neuraldem.errors import ConfigError, DataError
from neuraldem.export.formats import (
    EXIT_RULES,
    FORMAT_VERSION,
    FORMATS,
    MATERIAL,
    METADATA,
    MIN_SNAPSHOTS,
    PARTS,
    SplitWriter,
    StepStatistics,
    Trajectory,
    apply_exit_rule,
    exit_steps,
    kept_length,
    read_metadata,
    tool_metadata,
)
from neuraldem.gns.datamodule import CONDITIONING, SCENES, SPLITS, ParticleRun

TOOL = {"gns": "GNS", "lagrangebench": "LagrangeBench"}
CASE = {"hopper": "HOPPER", "fluidized_bed": "FLUIDIZED_BED"}
# kinds that have particles but not a fixed set of them over a trajectory
GROWING = {"hopper_refill": "particles are inserted during its runs (the particle set grows over a trajectory)"}
EXIT_TEXT = {
    "refuse": "no particle leaves any exported run (runs with exits were refused)",
    "truncate": "each trajectory ends before the first snapshot at which a particle is gone",
    "hold": "a particle that left stays at its last position; exit_step_<split>.npz holds, per trajectory, the "
            "first snapshot at which each particle is gone (T = never); their steps are left out of the statistics",
}


@dataclass
class RunSurvey:
    """What pass 1 learns of one run before anything is written."""

    record: SimRecord
    n_snapshots: int
    n_particles: int
    n_exited: int
    kept: int  # snapshots kept under the exit rule
    dt: float
    diameter: float
    box_lo: np.ndarray
    box_hi: np.ndarray
    length: int = 0  # snapshots written (LagrangeBench: the split's shortest)


@dataclass
class ExportPlan:
    fmt: str
    dataset_dir: Path
    manifest: Manifest
    split: str
    exits: str
    radius_d: float
    material: str | None
    runs: dict[str, list[RunSurvey]] = field(default_factory=dict)

    @property
    def all_runs(self) -> list[RunSurvey]:
        return [r for part in PARTS for r in self.runs[part]]


def check_kind(m: Manifest, dataset_dir: Path, fmt: str) -> None:
    if m.kind in SCENES:
        return
    tool = TOOL[fmt]
    if m.kind in GROWING:
        raise DataError(f"dataset {dataset_dir} is of kind {m.kind!r}, which the {tool} format cannot hold: "
                        f"{GROWING[m.kind]}, and {tool} stores one fixed particle set per trajectory")
    raise DataError(f"dataset {dataset_dir} is of kind {m.kind!r}, which the {tool} format cannot hold: it has "
                    f"no particle trajectories to export (neuraldem export reads {' and '.join(SCENES)} datasets)")


def material_property(choice: str, m: Manifest, records: list[SimRecord], fmt: str) -> str | None:
    """The conditioning scalar the GNS npz carries per trajectory: `auto` is the scene's when it has one (the
    bed's inlet velocity), `none` none; LagrangeBench has no place for one."""
    if fmt != "gns" and choice not in ("auto", "none"):
        raise ConfigError(f"material_property={choice!r}: the LagrangeBench format has no place for one (the "
                          "conditioning scalars are in metadata.json either way)")
    if fmt != "gns" or choice == "none":
        return None
    if choice == "auto":
        defaults = CONDITIONING[m.kind]
        return defaults[0] if len(defaults) == 1 else None
    missing = [r.sim_id for r in records if choice not in r.conditioning()]
    if missing:
        known = sorted(set.intersection(*(set(r.conditioning()) for r in records)))
        raise ConfigError(f"material_property={choice!r}: runs {', '.join(missing[:3])} have no such scalar "
                          f"(every run has: {', '.join(known)}; or none)")
    return choice


def survey(plan: ExportPlan) -> None:
    """Pass 1: read and validate every run of the split, apply the exit rule's checks, and measure what the
    files need (lengths, box, dt), so that a refusal comes before anything is written."""
    m, rule = plan.manifest, plan.exits
    for part in PARTS:
        plan.runs[part] = []
        for sim_id in m.split_ids(plan.split, part):
            rec = m.record(sim_id)
            if not rec.usable:
                raise DataError(f"simulation {sim_id} of {plan.dataset_dir} is in split {plan.split!r} but not "
                                f"finished (status {rec.status})", "rerun datagen, or choose another split=")
            with ParticleRun(plan.dataset_dir / str(rec.file), m.kind, m.scene) as run:
                x = run.positions()
                es = exit_steps(x)
                s = RunSurvey(rec, len(x), x.shape[1], int((es < len(x)).sum()), kept_length(es, len(x), rule),
                              run.dt, float(np.mean(run.diameters)), np.asarray(run.box_lo, float),
                              np.asarray(run.box_hi, float))
            check_exits(plan, s, int(es.min()))
            plan.runs[part].append(s)
    if not plan.runs["train"]:
        raise DataError(f"split {plan.split!r} of {plan.dataset_dir} has no training runs: the statistics come "
                        "from them", "choose another split=, or generate more runs")
    dts = sorted({round(s.dt, 12) for s in plan.all_runs})
    if dts[-1] - dts[0] > 1e-9 * dts[-1]:
        raise DataError(f"runs of {plan.dataset_dir} have different snapshot intervals {dts}: both formats have "
                        "one dt per dataset")
    for part in PARTS:
        common = min((s.kept for s in plan.runs[part]), default=0)
        for s in plan.runs[part]:
            s.length = common if plan.fmt == "lagrangebench" else s.kept


def check_exits(plan: ExportPlan, s: RunSurvey, first: int) -> None:
    name = f"run {s.record.sim_id} of {plan.dataset_dir}"
    if plan.exits == "refuse" and s.n_exited:
        raise DataError(f"{name}: {s.n_exited} of {s.n_particles} particles leave (the first gone at snapshot "
                        f"{first} of {s.n_snapshots}), and {TOOL[plan.fmt]} stores one fixed particle set per "
                        "trajectory", "choose exits=truncate (cut each trajectory before its first exit) or "
                        "exits=hold (exited particles stay at their last position; docs/exports.md)")
    if plan.exits == "truncate" and s.kept < MIN_SNAPSHOTS:
        raise DataError(f"{name}: only {s.kept} snapshots before its first particle leaves; exits=truncate "
                        f"needs {MIN_SNAPSHOTS}", "use exits=hold (docs/exports.md)")


def check_out(out: Path, force: bool) -> None:
    if not out.exists():
        return
    if not out.is_dir():
        raise DataError(f"{out} exists and is not a folder: choose a new folder for the export")
    if not any(out.iterdir()):
        return
    if not force:
        raise DataError(f"{out} exists and is not empty: choose a new folder, or pass force=true to replace an "
                        "earlier export there")
    try:
        read_metadata(out)
    except DataError:
        raise DataError(f"{out} is not empty and not an earlier export (no {METADATA} written by neuraldem "
                        "export): force=true replaces only those; choose a new folder") from None


def write(plan: ExportPlan, folder: Path) -> dict[str, Any]:
    """Pass 2: the split files and metadata.json into `folder`; returns the metadata."""
    m, fmt = plan.manifest, plan.fmt
    runs = plan.all_runs
    lo = np.min([s.box_lo for s in runs], axis=0)
    hi = np.max([s.box_hi for s in runs], axis=0)
    counts = {s.n_particles for s in runs}
    n_pad = max(counts) if fmt == "lagrangebench" and len(counts) > 1 else None
    stats = StepStatistics()
    listed: dict[str, list[dict[str, Any]]] = {}
    for part in PARTS:
        listed[part] = []
        if not plan.runs[part]:
            continue
        writer = SplitWriter(folder, fmt, part, plan.material, n_pad, write_exits=plan.exits == "hold")
        try:
            for s in plan.runs[part]:
                with ParticleRun(plan.dataset_dir / str(s.record.file), m.kind, m.scene, validate=False) as run:
                    x, exit_step = apply_exit_rule(run.positions(), "truncate" if plan.exits == "truncate" else
                                                   "hold")
                traj = Trajectory(s.record.sim_id, (x[: s.length] - lo).astype(np.float32),
                                  np.full(s.n_particles, MATERIAL, dtype=np.int64), np.minimum(exit_step, s.length),
                                  s.record.conditioning())
                key = writer.add(traj)
                if part == "train":
                    stats.add(traj)
                listed[part].append({"key": key, "sim_id": s.record.sim_id, "conditioning": traj.conditioning,
                                     "n_snapshots_stored": s.n_snapshots, "n_snapshots": s.length,
                                     "n_particles": s.n_particles,
                                     "n_exited": int((traj.exit_step < s.length).sum())})
        finally:
            writer.close()
    diameter = float(np.mean([s.diameter for s in runs]))
    lengths = {part: [s.length for s in plan.runs[part]] for part in PARTS}
    meta = tool_metadata(fmt, dim=3, dt=runs[0].dt, bounds=np.stack([lo - lo, hi - lo], axis=1),
                         radius=plan.radius_d * diameter, diameter=diameter, case=CASE[m.kind],
                         solver=str(m.solver.get("name", "")), lengths=lengths, n_particles_max=max(counts),
                         stats=stats.to_dict(), material_property=plan.material is not None)
    meta["neuraldem"] = {
        "format": fmt, "format_version": FORMAT_VERSION, "written_by": f"neuraldem {__version__}",
        "dataset": m.name, "dataset_dir": str(plan.dataset_dir.resolve()), "kind": m.kind, "scene": m.scene,
        "split": plan.split, "exits": plan.exits, "exit_rule": EXIT_TEXT[plan.exits],
        "origin": lo.tolist(),
        "units": "m and s; positions relative to origin (bounds start at 0); vel_* per snapshot step [m/step], "
                 "acc_* per step^2 [m/step^2], from the training part only",
        "particle_types": {str(MATERIAL): "granular particle (free material); walls are not exported",
                           "-1": "padding up to num_particles_max (LagrangeBench, only when counts differ)"},
        "particle_diameter": diameter, "connectivity_radius_d": plan.radius_d,
        "material_property": plan.material, "trajectories": listed,
    }
    (folder / METADATA).write_text(json.dumps(meta, indent=1))
    return meta


def export_dataset(fmt: str, dataset_dir: Path, out: Path, split: str | None = None, exits: str = "refuse",
                   radius_d: float = 2.0, material: str = "auto", force: bool = False) -> dict[str, Any]:
    """Write the export of `dataset_dir` into `out` (all or nothing: a refusal or a failure leaves no partial
    folder) and return its metadata."""
    checks.one_of("FORMAT", fmt, FORMATS)
    checks.one_of("exits", exits, EXIT_RULES)
    checks.positive("radius_d", radius_d)
    dataset_dir, out = Path(dataset_dir), Path(out).expanduser()
    m = require_dataset(dataset_dir, dataset_dir.name)
    check_kind(m, dataset_dir, fmt)
    split = split or SPLITS[m.kind][0]
    if split not in m.splits:
        raise ConfigError(f"split={split!r}: dataset {dataset_dir} has splits {', '.join(sorted(m.splits))}")
    check_out(out, force)
    records = [m.record(i) for part in PARTS for i in m.split_ids(split, part)]
    plan = ExportPlan(fmt, dataset_dir, m, split, exits, radius_d, material_property(material, m, records, fmt))
    survey(plan)
    tmp = out.with_name(f".{out.name}.partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        meta = write(plan, tmp)
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return meta


def summary(meta: dict[str, Any], out: Path) -> str:
    info = meta["neuraldem"]
    parts = ", ".join(f"{PARTS[p]} {len(info['trajectories'][p])}" for p in PARTS)
    held = sum(t["n_exited"] for p in PARTS for t in info["trajectories"][p])
    empty = [PARTS[p] for p in PARTS if not info["trajectories"][p]]
    lines = [f"{TOOL[info['format']]} export of {info['dataset']} (split {info['split']}, exits {info['exits']}) "
             f"in {out}: {parts} trajectories"]
    if held:
        lines.append(f"  {held} particles held at their last position after leaving (exit_step_*.npz)")
    if empty:
        lines.append(f"  no runs for {', '.join(empty)}: no file written for {'it' if len(empty) == 1 else 'them'}")
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = doc_parser("neuraldem.export", __doc__)
    p.add_argument("format", choices=FORMATS, help="gns (npz) or lagrangebench (HDF5)")
    p.add_argument("dataset", help="dataset dir, or a dataset name under <data dir>/datasets")
    p.add_argument("out", type=Path, help="folder to write (new, empty, or an earlier export with force=true)")
    p.add_argument("--split", default=None, help="split of the manifest (default: the scene's first)")
    p.add_argument("--exits", choices=EXIT_RULES, default="refuse",
                   help="what to do with particles that leave (default: refuse runs that have any)")
    p.add_argument("--radius-d", type=float, default=2.0,
                   help="default_connectivity_radius in mean particle diameters (default 2)")
    p.add_argument("--material-property", default="auto",
                   help="gns: conditioning scalar stored per trajectory (auto: the bed's inlet_velocity, none "
                        "for the hopper; a scalar name; none)")
    p.add_argument("--force", action="store_true", help="replace an earlier export in OUT")
    return p.parse_args(argv)


def scene_exports() -> dict[str, tuple[str, str]]:
    """What the scenes export besides the particle formats (`Scene.exports`, e.g. the hopper's pack / unpack)."""
    from neuraldem.scenes import registry

    return {name: entry for s in registry().values() for name, entry in s.exports.items()}


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    extra = scene_exports()
    if argv and argv[0] in extra:
        sys.argv[0] = "neuraldem export"  # the scene's parser names its object (`pack`, `unpack`)
        return int(importlib.import_module(extra[argv[0]][0]).main(argv) or 0)
    a = parse_args(argv)
    meta = export_dataset(a.format, find_dataset(a.dataset), a.out, a.split, a.exits, a.radius_d,
                          a.material_property, a.force)
    print(summary(meta, a.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
