"""Score a fluidized-bed model against CFD-DEM with the ground truth's own metric functions.

For every held-out inlet velocity (one trajectory per velocity of the split's test part, plus the long test
trajectories) the model is rolled out from the trajectory's first snapshot for max(horizons) x the training
horizon (the length of the training trajectories, in steps). Compared with the CFD-DEM trajectory over the
steps both have (the "window"): per-cell time mean / std of solid fraction, fluid speed and mixing (relative
L2 per field, slice maps side by side; `rel_l2_full`: the whole rollout's statistics against the whole
trajectory's), Lacey index curves (mean absolute difference), bed height and bubble
fraction statistics (`neuraldem.scenes.fluidized_bed.analysis.metrics`, the functions that scored the data). Over the
whole
rollout: total solid volume (drift in %) and stability (steps until divergence; stable or not at 1x, 3x, 10x the
training horizon). A chaotic bed is not compared step by step: trajectories decorrelate, their statistics
should not.

Outputs: metrics.json, report.md, time_averages_<sim>.png, curves_<sim>.png, solid_volume.png,
rollouts/<sim>.h5 (same layout as `python -m neuraldem.rollout` writes) and, with vtk, vtk/ for the first.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.config import checks
from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import DataError
from neuraldem.eval.checkpoints import IMPORTED_SPLIT, checkpoint_dataset, read_checkpoint, resolve_device
from neuraldem.machine import machine_info
from neuraldem.paths import invocation
from neuraldem.scenes.fluidized_bed.analysis import metrics as fm
from neuraldem.scenes.fluidized_bed.analysis import plots as fb_plots
from neuraldem.scenes.fluidized_bed.dataset.report import metric_settings
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.option_aliases import RESULT_CONSERVE_KEY
from neuraldem.scenes.fluidized_bed.surrogate.options import RolloutOptions
from neuraldem.scenes.fluidized_bed.surrogate.rollout import (
    DEFAULT_INIT_SNAPSHOT,
    DivergenceLimits,
    ModelStepper,
    Rollout,
    Stepper,
    initial_state,
    rollout,
)
from neuraldem.scenes.fluidized_bed.surrogate.rollout_run import (
    RolloutFile,
    check_grid,
    check_velocity,
    load_fb_checkpoint,
    write_rollout,
    write_rollout_vtk,
)
from neuraldem.sim.foam_reader import BoxGrid

DEFAULT_HORIZONS = (1, 3, 10)
STAT_FIELDS = ("solid_fraction_mean", "solid_fraction_std", "fluid_speed_mean", "fluid_speed_std", "mixing_mean",
               "mixing_std")


@dataclass
class FieldSeries:
    """Grid fields over time, from a dataset file or a rollout: what every metric here reads."""

    times: np.ndarray
    solid_fraction: np.ndarray  # (T, nx, ny, nz)
    fluid_velocity: np.ndarray  # (T, nx, ny, nz, 3)
    mixing: np.ndarray  # (T, nx, ny, nz)
    grid: BoxGrid
    particle_volume: float  # mean volume of one particle [m^3]
    total_particle_volume: float  # what the solid fraction should integrate to [m^3]

    @classmethod
    def from_dataset_file(cls, f: BedFile) -> FieldSeries:
        return cls(f.times, f.solid_fraction(), f.fluid_velocity(), f.mixing(), f.grid,
                   float(np.mean(f.particle_volumes)), float(f.particle_volumes.sum()))

    @classmethod
    def from_rollout_file(cls, r: RolloutFile) -> FieldSeries:
        return cls(r.times, r.grid_field("solid_fraction"), r.grid_field("fluid_velocity"), r.grid_field("mixing"),
                   r.grid, r.particle_volume, r.total_volume)

    def since(self, k: int) -> FieldSeries:
        """The series from snapshot k on (a rollout started at snapshot k is compared with this)."""
        return FieldSeries(self.times[k:], self.solid_fraction[k:], self.fluid_velocity[k:], self.mixing[k:],
                           self.grid, self.particle_volume, self.total_particle_volume)

    def window(self, n: int) -> FieldSeries:
        return FieldSeries(self.times[:n], self.solid_fraction[:n], self.fluid_velocity[:n], self.mixing[:n],
                           self.grid, self.particle_volume, self.total_particle_volume)


def time_statistics(s: FieldSeries) -> dict[str, np.ndarray]:
    """Per-cell time mean and std of solid fraction, fluid speed and mixing."""
    out = {}
    for name, values in (("solid_fraction", s.solid_fraction), ("fluid_speed", fm.fluid_speed(s.fluid_velocity)),
                         ("mixing", s.mixing)):
        out[f"{name}_mean"], out[f"{name}_std"] = fm.time_statistics(values)
    return out


def relative_l2(pred: np.ndarray, truth: np.ndarray) -> float:
    norm = float(np.linalg.norm(truth))
    return float(np.linalg.norm(pred - truth) / norm) if norm > 0 else float("nan")


def curves(s: FieldSeries, settings: dict[str, Any]) -> dict[str, Any]:
    """Metric series over time (the layout `fb_plots` draws)."""
    z = s.grid.edges(2)
    h = fm.bed_height(s.solid_fraction, z, settings["bed_quantile"])
    return {
        "time": s.times, "bed_height": h,
        "bubble_fraction": fm.bubble_fraction(s.solid_fraction, z, h, settings["bubble_threshold"]),
        "lacey_field": fm.lacey_from_fields(s.solid_fraction, s.mixing, s.grid.cell_volume, s.particle_volume,
                                            tuple(settings["lacey_block"]), float(settings["lacey_min_count"])),
        "solid_volume": fm.total_solid_volume(s.solid_fraction, s.grid.cell_volume),
        "particle_volume_total": s.total_particle_volume,
    }


def summary(s: FieldSeries, settings: dict[str, Any]) -> dict[str, float]:
    """`fb_summary`, the scalar metrics the dataset's manifest holds for every trajectory."""
    return fm.fb_summary(s.times, s.solid_fraction, s.mixing, s.fluid_velocity, s.grid.edges(2),
                         s.grid.cell_volume, s.particle_volume, s.total_particle_volume,
                         tuple(settings["lacey_block"]), float(settings["lacey_min_count"]),
                         settings["bed_quantile"], settings["bubble_threshold"])


def mass(s: FieldSeries) -> dict[str, float]:
    """Total solid volume over the whole series, in % of its initial value and of the particles' volume."""
    vol = fm.total_solid_volume(s.solid_fraction, s.grid.cell_volume)
    return {"steps": len(vol) - 1, "drift_pct": float(100 * (vol[-1] / vol[0] - 1)),
            "max_drift_pct": 100 * fm.mass_conservation_error(vol),
            "max_error_vs_particles_pct": 100 * fm.mass_conservation_error(vol, s.total_particle_volume)}


def compare(pred: FieldSeries, truth: FieldSeries, settings: dict[str, Any]) -> dict[str, Any]:
    """Prediction vs ground truth: statistics over the common window, mass over each whole series."""
    n = min(len(pred.times), len(truth.times))
    p, t = pred.window(n), truth.window(n)
    sp, st = time_statistics(p), time_statistics(t)
    full_p, full_t = time_statistics(pred), time_statistics(truth)
    cp, ct = curves(p, settings), curves(t, settings)
    lacey_diff = np.abs(cp["lacey_field"] - ct["lacey_field"])
    sum_p, sum_t = summary(p, settings), summary(t, settings)
    return {
        "window_steps": n - 1,
        "truth_steps": len(truth.times) - 1,  # > window_steps for a short baseline against a long trajectory
        "rel_l2": {k: relative_l2(sp[k], st[k]) for k in STAT_FIELDS},
        # the whole rollout's statistics against the whole CFD-DEM trajectory's (a bed forgets its start, so
        # a 10x rollout should reproduce the statistics of a shorter trajectory at the same velocity)
        "rel_l2_full": {k: relative_l2(full_p[k], full_t[k]) for k in STAT_FIELDS},
        "mass": mass(pred), "mass_truth": mass(truth),
        "lacey": {"mae": float(np.nanmean(lacey_diff)) if np.isfinite(lacey_diff).any() else float("nan"),
                  "final_pred": sum_p["lacey_final"], "final_truth": sum_t["lacey_final"],
                  "time_to_0.5_pred": sum_p["lacey_time_to_0.5"], "time_to_0.5_truth": sum_t["lacey_time_to_0.5"]},
        "bed_height": {"mean_pred": sum_p["bed_height_mean"], "mean_truth": sum_t["bed_height_mean"],
                       "std_pred": sum_p["bed_height_std"], "std_truth": sum_t["bed_height_std"]},
        "bubble_fraction": {"mean_pred": sum_p["bubble_fraction_mean"], "mean_truth": sum_t["bubble_fraction_mean"],
                            "max_pred": sum_p["bubble_fraction_max"], "max_truth": sum_t["bubble_fraction_max"]},
        "summary_pred": sum_p, "summary_truth": sum_t,
        # a lean / one-sided bubble channel of the solid fraction's statistics, and the error's lateral part
        "structure": fm.left_right_structure(sp["solid_fraction_mean"], sp["solid_fraction_std"],
                                             st["solid_fraction_mean"], st["solid_fraction_std"]),
    }


def concatenate(series: Sequence[FieldSeries]) -> FieldSeries:
    """Independent trajectories end to end, for statistics over all of their snapshots (times are not
    monotonic: only per-cell statistics read the result)."""
    first = series[0]
    return FieldSeries(np.concatenate([s.times for s in series]),
                       np.concatenate([s.solid_fraction for s in series]),
                       np.concatenate([s.fluid_velocity for s in series]),
                       np.concatenate([s.mixing for s in series]), first.grid, first.particle_volume,
                       first.total_particle_volume)


def compare_pooled(pred: FieldSeries, pooled: Sequence[FieldSeries], settings: dict[str, Any],
                   sims: Sequence[str]) -> dict[str, Any]:
    """The whole rollout's statistics against CFD-DEM's pooled over every trajectory at the velocity.

    Why: one 3-s trajectory is a short sample of a chaotic bed, so a 3000-step rollout compared with it
    scores the sampling noise of the reference as much as the model (a persistent one-sided bubble channel,
    visible only over tens of seconds, hides in it). All packings at a velocity are independent realizations of
    the same statistics: per-cell mean and std over all their snapshots together estimate the long-time
    statistics better (3 packings x 3 s = 9 s in fb_small), and the Lacey curve is compared with their mean
    curve (over the steps every one of them and the rollout have)."""
    if not pooled:
        raise DataError("compare_pooled needs at least one CFD-DEM trajectory", fix="pass the velocity's runs")
    sp, st = time_statistics(pred), time_statistics(concatenate(pooled))
    n = min(len(pred.times), *(len(s.times) for s in pooled))
    lacey_p = curves(pred.window(n), settings)["lacey_field"]
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns (too few particles) stay NaN
        lacey_t = np.nanmean([curves(s.window(n), settings)["lacey_field"] for s in pooled], axis=0)
    diff = np.abs(lacey_p - lacey_t)
    return {"sims": list(sims), "snapshots": int(sum(len(s.times) for s in pooled)),
            "pred_snapshots": len(pred.times), "lacey_steps": n - 1,
            "rel_l2": {k: relative_l2(sp[k], st[k]) for k in STAT_FIELDS},
            "lacey_mae": float(np.nanmean(diff)) if np.isfinite(diff).any() else float("nan"),
            "structure": fm.left_right_structure(sp["solid_fraction_mean"], sp["solid_fraction_std"],
                                                 st["solid_fraction_mean"], st["solid_fraction_std"])}


def velocity_twins(m: Manifest, rec: SimRecord) -> list[SimRecord]:
    """Every finished trajectory at `rec`'s inlet velocity (rec included), by id: the pooled reference."""
    v = round(float(rec.params["inlet_velocity"]), 6)
    return sorted((r for r in m.usable() if round(float(r.params["inlet_velocity"]), 6) == v and r.file),
                  key=lambda r: r.sim_id)


def pooled_reference(m: Manifest, dataset_dir: Path, rec: SimRecord, init_snapshot: int,
                     leave_out: str | None = None) -> tuple[list[str], list[FieldSeries]]:
    """The trajectories at `rec`'s velocity from `init_snapshot` on (without `leave_out`, a replayed one)."""
    ids, series = [], []
    for r in velocity_twins(m, rec):
        if r.sim_id == leave_out:
            continue
        with BedFile(dataset_dir / str(r.file)) as f:
            series.append(FieldSeries.from_dataset_file(f).since(init_snapshot))
        ids.append(r.sim_id)
    return ids, series


def stability(r: Rollout, horizon_steps: int, horizons: Sequence[int]) -> dict[str, Any]:
    """Steps until divergence (None = none) and, per horizon multiple, whether the rollout got that far."""
    lasted = r.steps_done
    return {"steps_to_divergence": r.diverged_at, "divergence": r.divergence, "steps_done": lasted,
            "horizons": [{"multiple": m, "steps": m * horizon_steps, "stable": lasted >= m * horizon_steps}
                         for m in horizons]}


@dataclass
class TrajectoryEvaluation:
    sim_id: str
    velocity: float
    result: dict[str, Any]  # JSON-ready numbers
    pred: FieldSeries  # the whole rollout
    truth: FieldSeries
    rollout: Rollout


def evaluate_trajectory(path: Path, sim_id: str, velocity: float, stepper: Stepper, steps: int,
                        horizon_steps: int, horizons: Sequence[int], settings: dict[str, Any],
                        limits: DivergenceLimits | None = None, rollout_path: Path | None = None,
                        attrs: dict[str, Any] | None = None, progress: bool = False,
                        init_snapshot: int = DEFAULT_INIT_SNAPSHOT) -> TrajectoryEvaluation:
    """Roll `stepper` out from snapshot `init_snapshot` of the trajectory and score it against the trajectory
    from that snapshot on.

    The rollout goes through its file (`rollout_path`) when given, so the numbers are those of the file a
    user gets from `neuraldem.rollout`."""
    with BedFile(path) as f:
        state = initial_state(f, init_snapshot)
        truth = FieldSeries.from_dataset_file(f).since(init_snapshot)
        r = rollout(stepper, state, steps, limits, progress=progress)
        if rollout_path is not None:
            write_rollout(rollout_path, r, f.grid, truth.particle_volume, truth.total_particle_volume, attrs or {})
    if rollout_path is not None:
        with RolloutFile(rollout_path) as rf:
            pred = FieldSeries.from_rollout_file(rf)
    else:
        pred = FieldSeries(r.times, r.solid_fraction.astype(np.float64), r.fluid_velocity.astype(np.float64),
                           r.mixing.astype(np.float64), truth.grid, truth.particle_volume, truth.total_particle_volume)
    result = {"sim_id": sim_id, "inlet_velocity": velocity, "steps_requested": steps, **(attrs or {}),
              "stability": stability(r, horizon_steps, horizons), **compare(pred, truth, settings)}
    return TrajectoryEvaluation(sim_id, velocity, result, pred, truth, r)


def held_out(m: Manifest, split: str, part: str, max_sims: int | None) -> list[SimRecord]:
    """One trajectory per held-out velocity (the first by id), then the part's long trajectories (the long test
    ones; a long validation set, data.parameters.long.part=val, lists its own as val)."""
    ids = m.split_ids(split, part) + m.splits.get("long", {}).get(part, [])
    chosen: dict[float, SimRecord] = {}
    for rec in sorted((m.record(i) for i in ids), key=lambda r: r.sim_id):
        if rec.usable:
            chosen.setdefault(round(float(rec.params["inlet_velocity"]), 6), rec)
    records = sorted(chosen.values(), key=lambda r: (r.params.get("duration", 0.0), r.params["inlet_velocity"]))
    return records[:max_sims]


def evaluate_checkpoint(ckpt: Path, out_dir: Path, datasets_dir: Path, dataset_dir: Path | None = None,
                        split: str | None = None, part: str = "test", max_sims: int | None = None,
                        horizons: Sequence[int] = DEFAULT_HORIZONS, limits: DivergenceLimits | None = None,
                        seed: int = 0, vtk: bool = True, device: str = "auto", progress: bool = True,
                        make_stepper: Callable[[Any, float], Stepper] | None = None,
                        init_snapshot: int = DEFAULT_INIT_SNAPSHOT,
                        options: RolloutOptions | None = None) -> dict[str, Any]:
    """Evaluate a fluidized-bed checkpoint on the held-out velocities, rolled out with `options` (None: as
    trained); write and return metrics.json."""
    horizons = [checks.positive_int(f"fluidized_bed.horizons[{i}]", h) for i, h in enumerate(horizons)]
    if not horizons:
        raise DataError("fluidized_bed.horizons is empty: give the horizon multiples to test, e.g. [1,3,10]")
    device = resolve_device(device)
    module = load_fb_checkpoint(ckpt, device)
    meta, norm = module.metadata, module.norm
    dataset_dir, m = checkpoint_dataset(meta, Path(ckpt), datasets_dir, dataset_dir)
    if m.scene.get("imported"):  # a user's own cases (scene checked above): every one of them
        split, records = IMPORTED_SPLIT, sorted(m.usable(), key=lambda r: r.sim_id)[:max_sims]
    else:
        split = split or meta["split"]
        records = held_out(m, split, part, max_sims)
    if not records:
        raise DataError(f"no {part} trajectories in split {split!r} of {dataset_dir}")
    settings = metric_settings(m)
    steps = max(horizons) * norm.horizon_steps
    given = options or RolloutOptions()
    make_stepper = make_stepper or (lambda mod, v: ModelStepper(mod, v, seed, device, given))
    stability = given.apply(module.stability)  # what every rollout runs with
    out_dir = Path(out_dir)
    (out_dir / "rollouts").mkdir(parents=True, exist_ok=True)
    results, volumes = [], {}
    for rec in records:  # one trajectory in memory at a time: figures and VTK are written as we go
        v = float(rec.params["inlet_velocity"])
        path = dataset_dir / str(rec.file)
        with BedFile(path) as f:
            check_grid(norm, f)
        attrs = {"extrapolation": check_velocity(norm, v), "checkpoint": str(Path(ckpt).resolve()),
                 "initial_state": f"{m.name}/{rec.sim_id} snapshot {init_snapshot}", "seed": seed,
                 RESULT_CONSERVE_KEY: stability.conserve_volume, "mixing": stability.mixing,
                 "mirror_alternate": stability.mirror_alternate, "rollout_noise": stability.rollout_noise}
        e = evaluate_trajectory(path, rec.sim_id, v, make_stepper(module, v), steps, norm.horizon_steps, horizons,
                                settings, limits, out_dir / "rollouts" / f"{rec.sim_id}.h5", attrs, progress,
                                init_snapshot)
        ids, reference = pooled_reference(m, dataset_dir, rec, init_snapshot)
        e.result["pooled"] = compare_pooled(e.pred, reference, settings, ids)
        del reference
        volumes |= write_trajectory_figures(e, settings, out_dir)
        if vtk and not results:
            write_rollout_vtk(out_dir / "vtk", e.sim_id, e.rollout, e.truth.grid)
        results.append(e.result)
    fb_plots.plot_solid_volume(volumes, out_dir / "solid_volume.png", "total solid volume of the solid fraction field")
    result = {
        "checkpoint": str(Path(ckpt).resolve()), "dataset": str(dataset_dir), "split": split, "part": part,
        "trained_velocity_range": [norm.velocity_lo, norm.velocity_hi], "dt": norm.dt,
        "training": {"input_noise": meta.get("input_noise", 0.0),
                     "push_forward_steps": meta.get("push_forward_steps", 1),
                     "parameters": sum(p.numel() for p in module.parameters()),
                     "solids_flux": bool(meta.get("solids_flux", False)),
                     "mirror": bool(meta.get("mirror", False)),
                     # a checkpoint trained with callbacks.ema holds the averaged weights (neuraldem.lit.ema)
                     "weights": "EMA" if "current_model_state" in read_checkpoint(ckpt).raw else "as trained",
                     "conserve_volume": module.stability.conserve_volume,
                     "trained_stability": module.stability.to_dict()},
        "training_horizon_steps": norm.horizon_steps, "horizons": horizons, "rollout_steps": steps,
        RESULT_CONSERVE_KEY: stability.conserve_volume, "stability": stability.to_dict(),
        "init_snapshot": init_snapshot,
        "limits": vars(limits or DivergenceLimits()), "metric_settings": settings,
        "aggregate": aggregate(results), "trajectories": results,
        "machine": machine_info(), "command": invocation(),
        "date_utc": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    atomic_write_json(out_dir / "metrics.json", _jsonable(result))
    from neuraldem.scenes.fluidized_bed.analysis.evaluation_report import markdown_report

    (out_dir / "report.md").write_text(markdown_report(result))
    return result


def aggregate(results: list[dict[str, Any]]) -> dict[str, Any]:
    def mean(values: list[float]) -> float:
        finite = [v for v in values if v is not None and np.isfinite(v)]
        return float(np.mean(finite)) if finite else float("nan")

    out = {"n_trajectories": len(results),
           "solid_fraction_mean_rel_l2": mean([r["rel_l2"]["solid_fraction_mean"] for r in results]),
           "solid_fraction_mean_rel_l2_full": mean([r["rel_l2_full"]["solid_fraction_mean"] for r in results]),
           "fluid_speed_mean_rel_l2": mean([r["rel_l2"]["fluid_speed_mean"] for r in results]),
           "mass_max_abs_drift_pct": max(abs(r["mass"]["drift_pct"]) for r in results),
           "mass_max_drift_during_pct": max(r["mass"]["max_drift_pct"] for r in results),
           "lacey_mae": mean([r["lacey"]["mae"] for r in results]),
           "n_extrapolation": sum(bool(r.get("extrapolation")) for r in results)}
    if all("pooled" in r for r in results):  # the whole rollout against every CFD-DEM run at its velocity
        out |= {"pooled_solid_fraction_mean_rel_l2": mean([r["pooled"]["rel_l2"]["solid_fraction_mean"]
                                                           for r in results]),
                "pooled_solid_fraction_std_rel_l2": mean([r["pooled"]["rel_l2"]["solid_fraction_std"]
                                                          for r in results]),
                "pooled_lacey_mae": mean([r["pooled"]["lacey_mae"] for r in results])}
    for h in results[0]["stability"]["horizons"]:
        out[f"stable_at_{h['multiple']}x"] = sum(
            next(x["stable"] for x in r["stability"]["horizons"] if x["multiple"] == h["multiple"]) for r in results)
    return out


POOLED_SCORE_KEYS = ("pooled_solid_fraction_mean_rel_l2", "pooled_solid_fraction_std_rel_l2", "pooled_lacey_mae")


def pooled_sum(terms: Sequence[float | None]) -> float | None:
    """The one number the bed's tables report and `report fb-select` ranks by: rel. L2 of the per-cell time mean
    + rel. L2 of the std field + Lacey MAE, each against every CFD-DEM run at the velocity (None if one is missing)."""
    return None if any(t is None for t in terms) else float(sum(terms))


def write_trajectory_figures(e: TrajectoryEvaluation, settings: dict[str, Any], out_dir: Path) -> dict[str, Any]:
    """Time-averaged maps, profiles across the bed and metric curves, CFD-DEM next to NeuralDEM; returns the
    solid-volume curves."""
    label = f"U0 = {e.velocity:.2f} m/s"
    n = min(len(e.pred.times), len(e.truth.times))
    g = e.truth.grid
    fb_plots.plot_time_averages({"CFD-DEM": time_statistics(e.truth.window(n)),
                                 "NeuralDEM": time_statistics(e.pred.window(n))}, (g.lo[0], g.hi[0], g.lo[2], g.hi[2]),
                                out_dir / f"time_averages_{e.sim_id}.png",
                                f"{label}: time averages over {n - 1} steps (central y slice)")
    c_pred, c_truth = curves(e.pred, settings), curves(e.truth, settings)
    fb_plots.plot_lateral_profiles({"CFD-DEM": time_statistics(e.truth), "NeuralDEM": time_statistics(e.pred)},
                                   g.axis_centres(0), g.axis_centres(2), float(np.mean(c_truth["bed_height"])),
                                   out_dir / f"lateral_profiles_{e.sim_id}.png",
                                   f"{label}: across the bed, whole series (CFD-DEM {len(e.truth.times) - 1} steps, "
                                   f"NeuralDEM {len(e.pred.times) - 1})")
    fb_plots.plot_curves({"CFD-DEM": c_truth, "NeuralDEM": c_pred}, out_dir / f"curves_{e.sim_id}.png",
                         f"{label}: bed height, bubble fraction, Lacey index")
    return {f"NeuralDEM {label}": c_pred, f"CFD-DEM {label}": c_truth}


def _jsonable(v: Any) -> Any:
    """NaN/inf as null (JSON has no NaN), numpy scalars as floats."""
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, (float, np.floating)):
        return float(v) if np.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    return v
