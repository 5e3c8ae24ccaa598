"""Stability map of the GNS baseline on the fluidized bed, in the shape of `fb_stability` (same JSON keys,
same figure), so its series sit beside the field surrogate's.

`neuraldem bench gns_stability ckpt=[GNS_CKPT,...] [labels=[NAME,...]]
[velocities=[V,...]] [n_velocities=9] [steps=N] [drift_limit_pct=5] [like=FB_JSON] [dataset=DIR]
[out=PATH]`
writes results/fluidized_bed/stability/gns_stability.json and .png.

For every GNS checkpoint (trained with experiment=gns_fb) and inlet velocity: one rollout of `steps=` steps
(default 10x the training horizon) from the first snapshots of the dataset trajectory closest in velocity
(`gns.rollout`). A rollout fails at the first state the GNS checks refuse (NaN/inf, a particle outside
the box, overlapping particles, a changed particle count) or when the solid volume of the kernel
solid-fraction field of its particles drifts beyond `drift_limit_pct=` (`fb_stability.assess`, the same
rule as for the field surrogate). `like=results/fluidized_bed/stability/fb_stability.json` rolls out at that
map's velocities and steps, and `neuraldem bench render` (or `neuraldem bench all gns_fb_ckpt=...`) then draws
both in one figure, stability_map.png.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from neuraldem.bench.report import machine_info, read_results, resolve_out
from neuraldem.cli import command_parser
from neuraldem.config import checks
from neuraldem.data.manifest import require_dataset
from neuraldem.errors import ConfigError, DataError
from neuraldem.gns.datamodule import ParticleRun
from neuraldem.gns.rollout import (
    Accelerator,
    StabilityLimits,
    fb_particle_fields,
    load_gns_checkpoint,
    model_accelerator,
    rollout,
)
from neuraldem.paths import data_dir
from neuraldem.scenes.fluidized_bed.bench.stability_map import (
    DEFAULT_DRIFT_LIMIT_PCT,
    DEFAULT_HORIZON_MULTIPLE,
    DEFAULT_N_VELOCITIES,
    assess,
    check_options,
    velocity_grid,
    write_map,
)
from neuraldem.scenes.fluidized_bed.surrogate.rollout_run import initial_file

NAME = "gns_stability"


def run(ckpts: list[Path], labels: list[str] | None = None, velocities: list[float] | None = None,
        n_velocities: int = DEFAULT_N_VELOCITIES, steps: int | None = None, dataset_dir: Path | None = None,
        drift_limit_pct: float = DEFAULT_DRIFT_LIMIT_PCT, limits: StabilityLimits | None = None,
        accelerate: Accelerator | None = None, progress: bool = True) -> dict[str, Any]:
    """The stability map of every GNS checkpoint over the same velocities and step count (fb_stability's
    JSON shape; `accelerate` replaces the models, for tests)."""
    labels = check_options(ckpts, labels, velocities, steps, drift_limit_pct, 0)
    checks.positive_int("n_velocities", n_velocities)
    limits = limits or StabilityLimits()
    modules = [load_gns_checkpoint(Path(c)) for c in ckpts]  # refuses other kinds before any rollout
    for c, m in zip(ckpts, modules, strict=False):
        if m.metadata["scene_kind"] != "fluidized_bed":
            raise DataError(f"{c} is a GNS of the {m.metadata['scene_kind']} scene; the stability map needs a "
                            "fluidized-bed GNS: train one with neuraldem train experiment=gns_fb")
    ranges = [(min(m.metadata["train_velocities"]), max(m.metadata["train_velocities"])) for m in modules]
    grid = sorted({round(float(v), 6) for v in velocities}) if velocities else \
        velocity_grid(min(r[0] for r in ranges), max(r[1] for r in ranges), n_velocities)
    steps = steps or DEFAULT_HORIZON_MULTIPLE * modules[0].norm.horizon_steps
    series = []
    for label, ckpt, module, (lo, hi) in zip(labels, ckpts, modules, ranges, strict=False):
        norm, meta, points = module.norm, module.metadata, []
        step_fn = accelerate or model_accelerator(module)
        for v in grid:
            path, source = initial_file(meta, Path(ckpt), v, data_dir() / "datasets", dataset_dir)
            m = require_dataset(path.parent.parent, meta["data_name"])
            with ParticleRun(path, "fluidized_bed", m.scene) as prun:
                r = rollout(step_fn, prun, norm, norm.scalars({"inlet_velocity": v}), steps, limits=limits)
                r.solid_fraction = fb_particle_fields(prun, r.positions[norm.history:])[0]
                cell_volume = prun.f.grid.cell_volume
            point = {"inlet_velocity": v, "extrapolation": not lo - 1e-9 <= v <= hi + 1e-9,
                     "initial_state": f"{source} snapshots 0 .. {norm.history}",
                     **assess(r, cell_volume, drift_limit_pct), "max_overlaps": max(r.overlaps, default=0)}
            points.append(point)
            if progress:
                print(f"{label}: U0 = {v:g} m/s: " + (f"failed at step {point['steps_to_failure']} "
                      f"({point['failure']})" if point["failed"] else f"{r.steps_done} steps stable"), flush=True)
        series.append({"label": label, "method": "gns", "checkpoint": str(Path(ckpt).resolve()),
                       "data_name": meta["data_name"], "trained_velocity_range": [lo, hi],
                       "training_horizon_steps": norm.horizon_steps, "dt": norm.dt,
                       "n_failed": sum(p["failed"] for p in points), "points": points})
    return {"velocities": grid, "steps": steps, "drift_limit_pct": drift_limit_pct, "seed": 0,
            "limits": {"box_tolerance_d": limits.box_tolerance_d, "overlap_fraction": limits.overlap_fraction,
                       "max_overlaps": limits.max_overlaps}, "series": series}


def main(argv: list[str]) -> int:
    p = command_parser(f"neuraldem.bench {NAME}", __doc__, summary=True)
    p.add_argument("--ckpt", type=Path, nargs="+", required=True, help="GNS checkpoints (experiment=gns_fb)")
    p.add_argument("--labels", nargs="+", default=None, help="series names, one per ckpt= (default: run folders)")
    p.add_argument("--velocities", type=float, nargs="+", default=None, help="inlet velocities [m/s]")
    p.add_argument("--n-velocities", type=int, default=DEFAULT_N_VELOCITIES, help="size of the default grid")
    p.add_argument("--steps", type=int, default=None,
                   help=f"rollout steps (default: {DEFAULT_HORIZON_MULTIPLE}x the first model's training horizon)")
    p.add_argument("--drift-limit-pct", type=float, default=DEFAULT_DRIFT_LIMIT_PCT,
                   help="a solid-volume drift beyond this [%%] is a failure")
    p.add_argument("--dataset", type=Path, default=None, help="dataset dir (default: <data dir>/datasets/<name>)")
    p.add_argument("--like", type=Path, default=None,
                   help="an fb_stability.json: take its velocities, steps and drift limit, so that the two maps "
                        "merge into one figure (bench render draws stability_map.png)")
    p.add_argument("--out", type=Path, default=None,
                   help=f"results JSON, or a folder for {NAME}.json (default "
                        f"results/fluidized_bed/stability/{NAME}.json)")
    a = p.parse_args(argv)
    out = resolve_out(a.out, NAME)
    if a.like is not None:
        if a.velocities is not None or a.steps is not None:
            raise ConfigError("like= takes the velocities and steps of its map: drop velocities= / steps=")
        like = read_results(a.like, "fb_stability")["results"]
        a.velocities, a.steps, a.drift_limit_pct = like["velocities"], like["steps"], like["drift_limit_pct"]
    check_options(a.ckpt, a.labels, a.velocities, a.steps, a.drift_limit_pct, 0)
    checks.positive_int("n_velocities", a.n_velocities)
    machine = machine_info()
    results = run(a.ckpt, a.labels, a.velocities, a.n_velocities, a.steps, a.dataset, a.drift_limit_pct)
    write_map(NAME, results, argv, out, machine)
    return 0
