"""The particle-based GNS baseline as points of the hopper's speed-accuracy chart.

Each GNS checkpoint (experiment=gns_hopper) is rolled out over the whole stored trajectory of the first
`n_sims` test simulations of its split (`gns.rollout`, from the first H + 1 stored snapshots). Its
drainage time, residual and outflow come from the predicted particles through the code that scores the
cheaper-LIGGGHTS points (`scenes.hopper.datagen.trajectory_metrics`, truth from the stored run the same way),
so the GNS, LIGGGHTS and the field surrogates answer the same questions with the same rulers.

Overlapping particles do not stop the rollout here (the chart asks what answer the baseline gives); the first
step with an overlapping pair is recorded per simulation. NaN/inf positions, particles leaving the domain box or
a changed particle count do stop it: such a rollout has no answer, the simulation counts as failed, and a point
with any failed simulation shows no error (listed under the figure with the reason). Time to answer = wall time
of the rollout, median over the simulations (one untimed warm-up step first); a rollout that stopped early is
timed per step and scaled to the whole trajectory (`timing.source` says so).
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.bench.timing import torch_threads
from neuraldem.config import checks
from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.errors import ConfigError, DataError
from neuraldem.eval.checkpoints import checkpoint_dataset, checkpoint_metadata, require_kind
from neuraldem.gns.datamodule import ParticleRun
from neuraldem.gns.module import GnsModule
from neuraldem.gns.rollout import (
    Accelerator,
    GnsRollout,
    StabilityLimits,
    load_gns_checkpoint,
    model_accelerator,
    rollout,
)
from neuraldem.paths import data_dir
from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings
from neuraldem.scenes.hopper.analysis.scoring import SimEvaluation, aggregate
from neuraldem.scenes.hopper.bench.runs import HOPPER_ERRORS
from neuraldem.scenes.hopper.bench.solver_variants import particle_evaluation
from neuraldem.scenes.hopper.dataset.datagen import trajectory_metrics
from neuraldem.scenes.hopper.solver import HopperTrajectory

# overlaps are counted (first overlap step recorded) but never stop a rollout of the chart
CHART_LIMITS = StabilityLimits(max_overlaps=2**62)


def exit_times(times: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """(N,) time of the first snapshot where a particle is gone (NaN), NaN if it never left."""
    gone = ~np.isfinite(positions[..., 2])  # (T, N)
    first = np.argmax(gone, axis=0)
    return np.where(gone.any(axis=0), times[first], np.nan)


def rollout_metrics(r: GnsRollout, stored: HopperTrajectory, diameter: float,
                    settings: HopperMetricSettings, horizon: float | None = None) -> dict[str, float]:
    """Scene metrics of a GNS rollout through datagen's ruler (fields at the initial particle positions). The
    given snapshots are the stored ones (the rollout drops particles that left before its start from them)."""
    positions = r.positions.copy()
    positions[:r.history + 1] = stored.positions[:r.history + 1]
    traj = dataclasses.replace(stored, times=r.times, positions=positions, velocities=None,
                               exit_times=exit_times(r.times, positions))
    return trajectory_metrics(traj, diameter, settings, horizon)


def require_hopper_gns(ckpt: Path, meta: dict[str, Any] | None = None) -> None:
    """Refuse a checkpoint that is not a GNS of the hopper, with a message (from its metadata alone, so a
    benchmark can check before it measures anything)."""
    meta = checkpoint_metadata(Path(ckpt)) if meta is None else meta
    require_kind(meta, "gns", Path(ckpt), "gns_ckpt=")
    if meta["scene_kind"] != "hopper":
        raise ConfigError(f"gns_ckpt={ckpt} is a GNS of the {meta['scene_kind']} scene: the hopper benchmarks need "
                          "one trained with experiment=gns_hopper")


def load_hopper_gns(ckpt: Path) -> GnsModule:
    """A GNS checkpoint of the hopper (`require_hopper_gns`)."""
    require_hopper_gns(ckpt)
    return load_gns_checkpoint(Path(ckpt))


def first_overlap_step(r: GnsRollout) -> int | None:
    return next((i + 1 for i, n in enumerate(r.overlaps) if n > 0), None)


def gns_point(ckpt: Path, n_sims: int = 3, dataset_dir: Path | None = None, threads: int = 1,
              label: str | None = None, accelerate: Accelerator | None = None) -> dict[str, Any]:
    """One chart point for a GNS checkpoint (module docstring); `accelerate` replaces the model (tests)."""
    checks.positive_int("gns_sims", n_sims)
    module = load_hopper_gns(Path(ckpt))
    meta, norm = module.metadata, module.norm
    dataset_dir, m = checkpoint_dataset(meta, Path(ckpt), data_dir() / "datasets", dataset_dir)
    ids = m.split_ids(meta["split"], "test") or m.split_ids(meta["split"], "val")
    if not ids:
        raise DataError(f"split {meta['split']!r} of {dataset_dir} has no test or validation run")
    records = [m.record(i) for i in ids[:n_sims]]
    settings = HopperMetricSettings()  # as the cheaper-LIGGGHTS points are scored (scenes.hopper.bench.solver_variants)
    diameter = float(m.scene["hopper"]["material"]["diameter"])
    step = accelerate or model_accelerator(module)
    evals, per_sim, failures, walls, cpus = [], [], [], [], []
    with torch_threads(threads):
        for rec in records:
            result, ev = _one_sim(rec, dataset_dir, m, norm, step, diameter, settings)
            per_sim.append(result)
            if ev is None:
                failures.append({"sim_id": rec.sim_id, "reason": f"step {result['failed_at']}: {result['failure']}"})
            else:
                evals.append(ev)
            # a rollout stopped early answered only part of the trajectory: its time is scaled to the whole
            done = result["steps_done"] + (1 if result["failed_at"] is not None else 0)
            scale = result["steps"] / max(done, 1)
            walls.append(result["rollout_wall_s"] * scale)
            cpus.append(result["rollout_cpu_s"] * scale)
    errors: dict[str, float] = {}
    agg: dict[str, float] = {}
    if evals and not failures:
        with warnings.catch_warnings():  # no transport/residence MSE for particles: their means are NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            agg = aggregate(evals)
        errors = {k: agg[k] for k in HOPPER_ERRORS}
    params = sum(p.numel() for p in module.parameters())
    return {"method": "GNS", "label": label or f"GNS {Path(ckpt).parent.parent.name}", "checkpoint": str(ckpt),
            "data_name": meta["data_name"], "split": meta["split"], "errors": errors, "aggregate": agg,
            "size": {"parameters": int(params)}, "n_sims": len(records), "n_failed": len(failures),
            "failures": failures, "simulations": per_sim,
            "time_to_answer_s": float(np.median(walls)), "cpu_s": float(np.median(cpus)),
            "timing": {"what": "one GNS rollout over the whole stored trajectory (median over simulations)",
                       "torch_threads": threads,
                       "source": ("extrapolated: time per step of the steps done x the trajectory's steps"
                                  if failures else "measured")}}


def _one_sim(rec: SimRecord, dataset_dir: Path, m: Manifest, norm: Any, step: Accelerator, diameter: float,
             settings: HopperMetricSettings) -> tuple[dict[str, Any], SimEvaluation | None]:
    path = dataset_dir / str(rec.file)
    with ParticleRun(path, "hopper", m.scene) as run:
        steps = run.n_snapshots - norm.history - 1
        scalars = norm.scalars(rec.conditioning())
        rollout(step, run, norm, scalars, 1, limits=CHART_LIMITS)  # warm-up (graph code paths, allocations)
        w0, c0 = time.perf_counter(), time.process_time()
        r = rollout(step, run, norm, scalars, steps, limits=CHART_LIMITS)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        # the stored run, from the file already open: the truth and the rollout's given snapshots
        stored = run.f.load() if r.failed_at is None else None
    result: dict[str, Any] = {"sim_id": rec.sim_id, "params": dict(rec.params), "steps": steps,
                              "steps_done": r.steps_done, "failed_at": r.failed_at, "failure": r.failure,
                              "first_overlap_step": first_overlap_step(r), "max_overlaps": max(r.overlaps, default=0),
                              "rollout_wall_s": wall, "rollout_cpu_s": cpu}
    if stored is None:
        return result, None
    horizon = m.scene.get("hopper", {}).get("max_time")
    truth = trajectory_metrics(stored, diameter, settings, horizon)  # = datagen's stored_metrics
    predicted = rollout_metrics(r, stored, diameter, settings, horizon)
    result.update(truth=truth, predicted=predicted)
    return result, particle_evaluation(rec, truth, predicted, settings)
