"""Stability map of fluidized-bed surrogates: how long a rollout stays physical, across the trained inlet
velocities and beyond them.

`neuraldem bench fb_stability ckpt=[CKPT,...] [labels=[NAME,...]] [velocities=[V,...]]
[n_velocities=9 | velocity_step=DV] [steps=N] [drift_limit_pct=5] [bed_limit_pct=10] [settle_steps=N]
[rollout.<option>=VALUE ...] [out=PATH]` writes results/fluidized_bed/stability/fb_stability.json and .png (the
rollout options of every command, `options.RolloutOptions`; left out: as each checkpoint was trained). A fine scan of
the trained range:
`velocity_step=0.005 steps=500`; of one stretch: `velocities=[2.000,2.002,...,2.100]`.

For every checkpoint (one series each, e.g. a model and its ablation without input noise) and every inlet
velocity: one rollout of `steps=` steps from snapshot 1 of the dataset trajectory closest in velocity
(`scenes.fluidized_bed.rollout`, as `neuraldem.rollout` does). A velocity fails when the rollout diverges (the rollout's
own detector: NaN/inf, solid fraction below 0 or above the maximum packing) or when the total solid volume
of the solid-fraction field drifts by more than `drift_limit_pct=` from the initial state's; steps to
failure is the first step at which either happens. Default velocities: 0.8x the lowest to 1.2x the highest
trained velocity (over all checkpoints), plus the two trained ends.

A rollout can stay finite and hold its mass and still leave the physics: a net with the velocity embedded at
scale 1000 settled into a bed 21 % lower than CFD-DEM's at one velocity inside its trained range, in a hole
0.004 m/s wide (results/fluidized_bed/options/velocity_embedding_scale1000_scan.png). So inside the trained range a
velocity also fails when the rollout's time-mean bed height (after `settle_steps=`, the bed's start-up from its
packing) is more than `bed_limit_pct=` from CFD-DEM's at that velocity: the time-mean bed heights of the
checkpoint's own training trajectories (the same start-up left out), linear in velocity between the two around
it. Outside the trained range there is no CFD-DEM to interpolate: the bed height is reported, not judged.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.bench import plots
from neuraldem.bench.choices import default_labels
from neuraldem.bench.report import command_line, machine_info, resolve_out, write_results
from neuraldem.cli import command_parser
from neuraldem.config import checks
from neuraldem.errors import ConfigError, DataError
from neuraldem.eval.checkpoints import checkpoint_dataset
from neuraldem.paths import data_dir
from neuraldem.scenes.fluidized_bed.analysis.metrics import bed_height, total_solid_volume
from neuraldem.scenes.fluidized_bed.dataset.report import metric_settings
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate import rollout as bed_rollout
from neuraldem.scenes.fluidized_bed.surrogate.module import BedModule
from neuraldem.scenes.fluidized_bed.surrogate.options import RolloutOptions, add_arguments
from neuraldem.scenes.fluidized_bed.surrogate.rollout_run import check_grid, initial_file, load_fb_checkpoint

NAME = "fb_stability"
DEFAULT_DRIFT_LIMIT_PCT = 5.0  # mass drift > 5 % is an unphysical state (docs/benchmarks.md, fb_stability)
DEFAULT_N_VELOCITIES = 9
DEFAULT_SPAN = (0.8, 1.2)  # the grid runs from 0.8x the lowest to 1.2x the highest trained velocity
DEFAULT_HORIZON_MULTIPLE = 10  # default steps=: 10x the training horizon, the longest horizon evaluation tests
# a time-mean bed height this far from CFD-DEM's is another regime, not noise: CFD-DEM's own runs 0.03 m/s apart
# differ by ~1 mm of ~42 (2 %); a collapsed bed was 21 % low (results/fluidized_bed/options/
# velocity_embedding_scale1000_scan.png)
DEFAULT_BED_LIMIT_PCT = 10.0
DEFAULT_SETTLE_FRACTION = 3  # default settle_steps=: a third of the training horizon (1 s of fb_small's 3 s)

# (module, inlet velocity, open file of the initial state) -> stepper; tests inject faulty steppers here
MakeStepper = Callable[[BedModule, float, BedFile], bed_rollout.Stepper]


def velocity_grid(lo: float, hi: float, n: int, span: tuple[float, float] = DEFAULT_SPAN,
                  step: float | None = None) -> list[float]:
    """`n` velocities evenly from span[0] * lo to span[1] * hi, plus lo and hi themselves (the edges of
    the trained range), sorted, rounded to 1e-6 m/s, without duplicates. With `step`: every `step` m/s from
    lo to hi instead (a fine scan of the trained range, where a net can fail between training velocities)."""
    checks.positive_int("n_velocities", n)
    if step is not None:
        checks.positive("velocity_step", step)
        grid = lo + step * np.arange(int(np.floor((hi - lo) / step + 1e-9)) + 1)
    else:
        grid = np.linspace(span[0] * lo, span[1] * hi, n) if n > 1 else np.array([lo])
    return sorted({round(float(v), 6) for v in (*grid, lo, hi)})


def assess(r: bed_rollout.Rollout, cell_volume: float, drift_limit_pct: float) -> dict[str, Any]:
    """Stability of one rollout: steps to divergence, the solid-volume drift (in % of the initial state's)
    at the end or at the last state before divergence, the first step beyond the drift limit, and the
    failure (the earlier of the two)."""
    volume = total_solid_volume(r.solid_fraction.astype(np.float64), cell_volume)
    drift = 100.0 * (volume / volume[0] - 1.0)
    beyond = np.flatnonzero(np.abs(drift) > drift_limit_pct)
    to_drift = int(beyond[0]) if beyond.size else None
    candidates = [(s, why) for s, why in (
        (r.diverged_at, f"diverged: {r.divergence}"),
        (to_drift, f"solid volume drift {drift[to_drift]:+.2f} % beyond {drift_limit_pct:g} %"
                   if to_drift is not None else ""),
    ) if s is not None]
    failed_at, failure = min(candidates, key=lambda c: c[0]) if candidates else (None, "")
    return {"steps_requested": r.steps_requested, "steps_done": r.steps_done,
            "steps_to_divergence": r.diverged_at, "divergence": r.divergence,
            "steps_to_drift_limit": to_drift, "drift_pct_end": float(drift[-1]),
            "max_abs_drift_pct": float(np.max(np.abs(drift))), "failed": failed_at is not None,
            "steps_to_failure": failed_at, "failure": failure,
            "steps_stable": failed_at if failed_at is not None else r.steps_done}


@dataclass
class BedReference:
    """CFD-DEM's time-mean bed height against inlet velocity: one point per training velocity of a checkpoint
    (runs at the same velocity averaged), each the mean over its snapshots after the start-up."""

    velocities: np.ndarray  # ascending, distinct [m/s]
    heights: np.ndarray  # [m]
    sim_ids: list[str]
    settle_steps: int
    quantile: float  # the dataset's bed-height quantile (metric settings), for the rollouts too

    def at(self, v: float) -> float | None:
        """Linear in velocity between the training velocities around v; None outside them."""
        if not len(self.velocities) or v < self.velocities[0] - 1e-9 or v > self.velocities[-1] + 1e-9:
            return None
        return float(np.interp(v, self.velocities, self.heights))

    def to_dict(self) -> dict[str, Any]:
        return {"velocities": self.velocities.tolist(), "bed_height_mm": (1e3 * self.heights).tolist(),
                "sim_ids": self.sim_ids, "settle_steps": self.settle_steps, "quantile": self.quantile}


def mean_bed_height(solid_fraction: np.ndarray, z_edges: np.ndarray, quantile: float) -> float | None:
    """Time mean of the bed height over the given frames; None when there are none."""
    if len(solid_fraction) == 0:
        return None
    h = bed_height(solid_fraction.astype(np.float64), z_edges, quantile)
    return float(np.nanmean(h)) if np.isfinite(h).any() else None


def bed_reference(module: BedModule, ckpt: Path, dataset_dir: Path | None,
                  settle_steps: int, init_snapshot: int = bed_rollout.DEFAULT_INIT_SNAPSHOT) -> BedReference:
    """The checkpoint's training trajectories (its recorded `split_ids`, else its split's training part): the
    mean bed height of each after `settle_steps` from the rollouts' initial snapshot."""
    meta = module.metadata
    ds, m = checkpoint_dataset(meta, Path(ckpt), data_dir() / "datasets", dataset_dir)
    quantile = float(metric_settings(m)["bed_quantile"])
    ids = (meta.get("split_ids") or {}).get("train") or m.split_ids(meta["split"], "train")
    by_velocity: dict[float, list[float]] = {}
    used = []
    for sim_id in ids:
        rec = m.record(sim_id)
        if not rec.usable:
            continue
        with BedFile(ds / str(rec.file)) as f:
            h = mean_bed_height(f.solid_fraction()[init_snapshot + settle_steps:], f.grid.edges(2), quantile)
        if h is not None:
            by_velocity.setdefault(round(float(rec.params["inlet_velocity"]), 6), []).append(h)
            used.append(sim_id)
    v = np.array(sorted(by_velocity))
    return BedReference(v, np.array([np.mean(by_velocity[x]) for x in v]), used, settle_steps, quantile)


def assess_bed(r: bed_rollout.Rollout, z_edges: np.ndarray, reference: BedReference, velocity: float,
               limit_pct: float) -> dict[str, Any]:
    """The rollout's time-mean bed height after the start-up against CFD-DEM's at its velocity; judged only
    inside the training velocities (`bed_checked`) and only when frames after the start-up exist."""
    h = mean_bed_height(r.solid_fraction[reference.settle_steps:], z_edges, reference.quantile)
    ref = reference.at(velocity)
    dev = 100.0 * (h / ref - 1.0) if h is not None and ref else None
    checked = dev is not None
    bad = checked and abs(dev) > limit_pct
    return {"bed_height_mm": None if h is None else 1e3 * h, "bed_height_cfd_mm": None if ref is None else 1e3 * ref,
            "bed_deviation_pct": dev, "bed_checked": checked, "bed_failed": bool(bad),
            "bed_failure": f"bed height {1e3 * h:.1f} mm, {dev:+.1f} % from CFD-DEM's {1e3 * ref:.1f} mm beyond "
                           f"{limit_pct:g} %" if bad else ""}


def check_options(ckpts: list[Path], labels: list[str] | None, velocities: list[float] | None,
                  steps: int | None, drift_limit_pct: float, seed: int,
                  bed_limit_pct: float = DEFAULT_BED_LIMIT_PCT, settle_steps: int | None = None,
                  velocity_step: float | None = None) -> list[str]:
    """Every option checked before anything is loaded or rolled out; returns the series labels."""
    if not ckpts:
        raise ConfigError("ckpt= is required: give one or more fluidized-bed checkpoints")
    if labels is not None and len(labels) != len(ckpts):
        raise ConfigError(f"labels=: {len(labels)} label(s) for {len(ckpts)} checkpoint(s): give one label per "
                          "ckpt=, or none (the run folder names are used)")
    labels = list(labels) if labels is not None else default_labels(ckpts)
    if len(set(labels)) != len(labels):
        raise ConfigError(f"labels={labels} has duplicates: give each checkpoint its own label")
    for i, v in enumerate(velocities or []):
        checks.positive(f"velocities[{i}]", v)
    if steps is not None:
        checks.positive_int("steps", steps)
    checks.number("drift_limit_pct", drift_limit_pct, lo=0.0, lo_open=True, hi=100.0)
    checks.number("bed_limit_pct", bed_limit_pct, lo=0.0, lo_open=True, hi=100.0)
    if settle_steps is not None:
        checks.positive_int("settle_steps", settle_steps, allow_zero=True)
    if velocity_step is not None:
        checks.positive("velocity_step", velocity_step)
        if velocities:
            raise ConfigError("velocity_step= and velocities= both given: give the velocities, or a step across "
                              "the trained range")
    checks.positive_int("seed", seed, allow_zero=True)
    return labels


def run(ckpts: list[Path], labels: list[str] | None = None, velocities: list[float] | None = None,
        n_velocities: int = DEFAULT_N_VELOCITIES, steps: int | None = None, dataset_dir: Path | None = None,
        drift_limit_pct: float = DEFAULT_DRIFT_LIMIT_PCT, seed: int = 0,
        limits: bed_rollout.DivergenceLimits | None = None,
        make_stepper: MakeStepper | None = None, progress: bool = True,
        options: RolloutOptions | None = None, bed_limit_pct: float = DEFAULT_BED_LIMIT_PCT,
        settle_steps: int | None = None, velocity_step: float | None = None) -> dict[str, Any]:
    """The stability map of every checkpoint over the same velocities and step count, rolled out with the
    given rollout options (None: as each checkpoint was trained)."""
    labels = check_options(ckpts, labels, velocities, steps, drift_limit_pct, seed, bed_limit_pct, settle_steps,
                           velocity_step)
    checks.positive_int("n_velocities", n_velocities)
    limits = limits or bed_rollout.DivergenceLimits()
    options = options or RolloutOptions()
    modules = [load_fb_checkpoint(Path(c)) for c in ckpts]  # refuses other kinds before any rollout
    ranges = [(m.norm.velocity_lo, m.norm.velocity_hi) for m in modules]
    grid = sorted({round(float(v), 6) for v in velocities}) if velocities else \
        velocity_grid(min(r[0] for r in ranges), max(r[1] for r in ranges), n_velocities, step=velocity_step)
    steps = steps or DEFAULT_HORIZON_MULTIPLE * modules[0].norm.horizon_steps
    if settle_steps is None:
        settle_steps = modules[0].norm.horizon_steps // DEFAULT_SETTLE_FRACTION
    make_stepper = make_stepper or (lambda module, v, f: bed_rollout.ModelStepper(module, v, seed, options=options))
    series = []
    for label, ckpt, module in zip(labels, ckpts, modules, strict=False):
        norm, points = module.norm, []
        reference = bed_reference(module, Path(ckpt), dataset_dir, settle_steps)
        for v in grid:
            path, source = initial_file(module.metadata, Path(ckpt), v, data_dir() / "datasets", dataset_dir)
            with BedFile(path) as f:
                check_grid(norm, f)
                start = bed_rollout.initial_state(f)
                r = bed_rollout.rollout(make_stepper(module, v, f), start, steps, limits, progress=False)
                cell_volume, z_edges = f.grid.cell_volume, f.grid.edges(2)
            point = {"inlet_velocity": v, "extrapolation": not norm.in_trained_range(v),
                     "initial_state": f"{source} snapshot 1", **assess(r, cell_volume, drift_limit_pct),
                     **assess_bed(r, z_edges, reference, v, bed_limit_pct)}
            point["ok"] = not point["failed"] and not point["bed_failed"]
            points.append(point)
            if progress:
                bed = "" if point["bed_height_mm"] is None else f", bed {point['bed_height_mm']:.1f} mm" + (
                    f" (CFD-DEM {point['bed_height_cfd_mm']:.1f}, {point['bed_deviation_pct']:+.1f} %)"
                    if point["bed_checked"] else "")
                print(f"{label}: U0 = {v:g} m/s: " + (f"failed at step {point['steps_to_failure']} "
                      f"({point['failure']})" if point["failed"] else f"{r.steps_done} steps stable")
                      + f", drift {point['drift_pct_end']:+.2f} %{bed}"
                      + (f": FAILED ({point['bed_failure']})" if point["bed_failed"] else ""), flush=True)
        series.append({"label": label, "checkpoint": str(Path(ckpt).resolve()),
                       "data_name": module.metadata["data_name"],
                       "trained_velocity_range": [norm.velocity_lo, norm.velocity_hi],
                       "training_horizon_steps": norm.horizon_steps, "dt": norm.dt,
                       "n_failed": sum(not p["ok"] for p in points),
                       "n_bed_failed": sum(p["bed_failed"] for p in points),
                       "bed_reference": reference.to_dict(), "points": points})
    return {"velocities": grid, "steps": steps, "drift_limit_pct": drift_limit_pct,
            "bed_limit_pct": bed_limit_pct, "settle_steps": settle_steps, "seed": seed,
            **options.as_dict(),
            "limits": {"max_packing": limits.max_packing, "tolerance": limits.tolerance}, "series": series}


def merge_maps(*maps: dict[str, Any]) -> dict[str, Any]:
    """One stability map from several (e.g. the field surrogates' and the GNS's), so that all series share a
    figure; refuses maps of other velocities, step counts or drift limits, which would not compare."""
    if not maps:
        raise DataError("merge_maps: no stability maps given")
    first = maps[0]
    for m in maps[1:]:
        for key in ("velocities", "steps", "drift_limit_pct"):
            if m[key] != first[key]:
                raise DataError(f"stability maps differ in {key} ({first[key]} vs {m[key]}): run both with the "
                                "same velocities=, steps= and drift_limit_pct= (gns_stability like=FB_JSON)")
    series = [dict(s, method=s.get("method", "field surrogate")) for m in maps for s in m["series"]]
    labels = [s["label"] for s in series]
    if len(set(labels)) != len(labels):
        raise DataError(f"stability maps share series labels {labels}: give each series its own labels=")
    return {**first, "limits": [m.get("limits") for m in maps], "series": series}


def write_map(name: str, results: dict[str, Any], argv: list[str], out: Path, machine: dict[str, Any]) -> None:
    """Write a stability map's JSON and figure and print each series' failures: the field surrogates' map and
    the GNS's are reported alike, so that they read (and merge) alike."""
    path = write_results(name, results, command=command_line(name, argv), path=out, machine=machine)
    plots.fb_stability_figure(results, path.with_suffix(".png"))
    for s in results["series"]:
        print(f"{s['label']}: {s['n_failed']} of {len(s['points'])} velocities failed within {results['steps']} steps")
    print(f"wrote {path} and {path.with_suffix('.png')}")


def main(argv: list[str]) -> int:
    p = command_parser(f"neuraldem.bench {NAME}", __doc__, summary=True)
    p.add_argument("--ckpt", type=Path, nargs="+", required=True,
                   help="fluidized-bed checkpoints, one series each (e.g. a model and its ablations)")
    p.add_argument("--labels", nargs="+", default=None, help="series names, one per --ckpt (default: run folders)")
    p.add_argument("--velocities", type=float, nargs="+", default=None,
                   help="inlet velocities [m/s] (default: n_velocities= from 0.8x the lowest to 1.2x the highest "
                        "trained velocity, plus the trained ends)")
    p.add_argument("--n-velocities", type=int, default=DEFAULT_N_VELOCITIES, help="size of the default grid")
    p.add_argument("--velocity-step", type=float, default=None,
                   help="instead: every this many m/s across the trained range (a fine scan, e.g. 0.005)")
    p.add_argument("--steps", type=int, default=None,
                   help=f"rollout steps (default: {DEFAULT_HORIZON_MULTIPLE}x the first model's training horizon)")
    p.add_argument("--drift-limit-pct", type=float, default=DEFAULT_DRIFT_LIMIT_PCT,
                   help="a solid-volume drift beyond this [%%] is a failure")
    p.add_argument("--bed-limit-pct", type=float, default=DEFAULT_BED_LIMIT_PCT,
                   help="inside the trained range, a time-mean bed height this far [%%] from CFD-DEM's (interpolated "
                        "in velocity between the training runs) is a failure")
    p.add_argument("--settle-steps", type=int, default=None,
                   help="steps of the bed's start-up left out of both bed heights (default: a third of the "
                        "training horizon)")
    p.add_argument("--dataset", type=Path, default=None,
                   help="dataset dir of the checkpoints' scene (default: <data dir>/datasets/<data name>)")
    p.add_argument("--seed", type=int, default=0, help="seed of the rollouts' particle re-sampling")
    add_arguments(p, default="as each checkpoint was trained")
    p.add_argument("--out", type=Path, default=None,
                   help=f"results JSON, or a folder for {NAME}.json (default "
                        f"results/fluidized_bed/stability/{NAME}.json); .png beside it")
    a = p.parse_args(argv)
    out = resolve_out(a.out, NAME)
    check_options(a.ckpt, a.labels, a.velocities, a.steps, a.drift_limit_pct, a.seed, a.bed_limit_pct,
                  a.settle_steps, a.velocity_step)
    checks.positive_int("n_velocities", a.n_velocities)
    machine = machine_info()
    results = run(a.ckpt, a.labels, a.velocities, a.n_velocities, a.steps, a.dataset, a.drift_limit_pct, a.seed,
                  options=RolloutOptions.from_args(a), bed_limit_pct=a.bed_limit_pct, settle_steps=a.settle_steps,
                  velocity_step=a.velocity_step)
    write_map(NAME, results, argv, out, machine)
    return 0
