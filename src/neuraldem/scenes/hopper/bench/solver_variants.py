"""The classical solver at cheaper settings, scored against the reference run of the same parameters.

A practitioner who needs an answer faster has choices besides a surrogate: fewer particles, coarser
particles, a larger timestep. Each variant of the dataset's scene is run for the parameters of a few
dataset simulations and scored with the functions that scored the dataset (`scenes.hopper.datagen.
trajectory_metrics`, i.e. `scenes.hopper.metrics` on fields at the initial particle positions) against the
stored reference run, then aggregated like a surrogate's evaluation (`scenes.hopper.scoring.aggregate`).
A variant whose runs fail (e.g. an unstable timestep) is recorded as failed, with the solver's reason.

Variants are written KIND:FACTOR:
  fewer:F    F x the particles (0 < F < 1), same hopper
  coarser:C  particle diameter x C (C > 1), particles / C^3 (same bulk volume)
  dt:K       timestep x K (K > 1); the snapshot interval must stay a multiple of it
  same:1     the reference settings re-run here (time measured on this machine; error shows reproducibility)
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.bench.timing import Sample
from neuraldem.cli import split_kind_factor
from neuraldem.data.manifest import SimRecord
from neuraldem.errors import ConfigError
from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings, flow_regime
from neuraldem.scenes.hopper.analysis.scoring import SimEvaluation, aggregate
from neuraldem.scenes.hopper.bench.runs import HOPPER_ERRORS
from neuraldem.scenes.hopper.bench.solver import run_scene
from neuraldem.scenes.hopper.dataset.datagen import stored_metrics, trajectory_metrics
from neuraldem.scenes.hopper.solver import STATUS_FAILED, HopperScene

KINDS = ("fewer", "coarser", "dt", "same")
DEFAULT_VARIANTS = ("same:1", "fewer:0.5", "fewer:0.25", "coarser:1.5", "coarser:2", "dt:2", "dt:5")


@dataclass(frozen=True)
class SolverVariant:
    kind: str
    factor: float

    @classmethod
    def parse(cls, spec: str) -> SolverVariant:
        kind, factor = split_kind_factor(spec)
        if kind not in KINDS or not np.isfinite(factor):
            raise ConfigError(f"solver variant {spec!r}: expected KIND:FACTOR with KIND one of {list(KINDS)}, "
                              "e.g. fewer:0.5, coarser:2, dt:2, same:1")
        ok = {"fewer": 0 < factor < 1, "coarser": factor > 1, "dt": factor > 1, "same": factor == 1}[kind]
        if not ok:
            need = {"fewer": "0 < F < 1", "coarser": "C > 1", "dt": "K > 1", "same": "1"}[kind]
            raise ConfigError(f"solver variant {spec!r}: the factor of {kind} must be {need}")
        return cls(kind, factor)

    @property
    def label(self) -> str:
        return "LIGGGHTS reference" if self.kind == "same" else f"LIGGGHTS {self.kind} x{self.factor:g}"

    @property
    def spec(self) -> str:
        return f"{self.kind}:{self.factor:g}"

    def apply(self, scene: HopperScene) -> HopperScene:
        mat = scene.material
        if self.kind == "fewer":
            out = replace(scene, n_particles=max(1, round(scene.n_particles * self.factor)))
        elif self.kind == "coarser":
            out = replace(scene, material=replace(mat, diameter=mat.diameter * self.factor),
                          n_particles=max(1, round(scene.n_particles / self.factor**3)))
        elif self.kind == "dt":
            out = replace(scene, material=replace(mat, dt=mat.dt * self.factor))
        else:
            out = scene
        out.validate(f"solver variant {self.spec}")
        return out


def score_variant(variant: SolverVariant, base: HopperScene, records: list[SimRecord], dataset_dir: Path,
                  workdir: Path, settings: HopperMetricSettings | None = None,
                  reference_cache: dict[str, dict[str, float]] | None = None) -> dict[str, Any]:
    """Run the variant for each record's parameters and seeds; errors against the stored reference runs.

    Time to answer = the run's wall time + computing the metrics from its particles (median over records)."""
    settings = settings or HopperMetricSettings()
    scene = variant.apply(base)
    cache = {} if reference_cache is None else reference_cache
    evals, costs, failures, per_sim = [], [], [], []
    for rec in records:
        if rec.sim_id not in cache:
            cache[rec.sim_id] = stored_metrics(Path(dataset_dir) / str(rec.file), base.material.diameter, settings,
                                              base.max_time)
        truth = cache[rec.sim_id]
        result = run_scene(scene, rec.params, Path(workdir) / f"{variant.kind}_{variant.factor:g}_{rec.sim_id}",
                           rec.index)
        if result.status == STATUS_FAILED or result.trajectory is None or result.solver is None:
            failures.append({"sim_id": rec.sim_id, "reason": result.reason})
            continue
        t0, c0 = time.perf_counter(), time.process_time()
        predicted = trajectory_metrics(result.trajectory, scene.material.diameter, settings, base.max_time)
        post = Sample(time.perf_counter() - t0, time.process_time() - c0)
        costs.append(Sample(result.solver.wall_s + post.wall_s, result.solver.cpu_s + post.cpu_s))
        evals.append(particle_evaluation(rec, truth, predicted, settings))
        per_sim.append({"sim_id": rec.sim_id, "status": result.status, "truth": truth, "predicted": predicted,
                        "solver_wall_s": result.solver.wall_s, "solver_cpu_s": result.solver.cpu_s,
                        "metrics_wall_s": post.wall_s})
    out: dict[str, Any] = {"method": "liggghts", "label": variant.label, "variant": variant.spec,
                           "scene": {"n_particles": scene.n_particles, "diameter": scene.material.diameter,
                                     "dt": scene.material.dt},
                           "n_sims": len(records), "n_failed": len(failures), "failures": failures,
                           "simulations": per_sim}
    if not evals:
        out.update(errors={}, time_to_answer_s=None, cpu_s=None)
        return out
    with warnings.catch_warnings():  # no transport/residence fields for a solver: their means are NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        agg = aggregate(evals)
    out.update(errors={k: agg[k] for k in HOPPER_ERRORS},
               aggregate=agg, time_to_answer_s=float(np.median([c.wall_s for c in costs])),
               cpu_s=float(np.median([c.cpu_s for c in costs])))
    return out


def particle_evaluation(rec: SimRecord, truth: dict[str, float], predicted: dict[str, float],
                        settings: HopperMetricSettings) -> SimEvaluation:
    """A run scored from particles (no transport/residence fields) in the shape `scenes.hopper.scoring.aggregate`
    takes, with each side's flow regime from its mass-flow index."""
    def with_regime(m: dict[str, float]) -> dict[str, float]:
        return {**m, "mass_flow": float(flow_regime(m["mass_flow_index"], settings.mass_flow_threshold) == "mass")}

    return SimEvaluation(sim_id=rec.sim_id, params=dict(rec.params), truth=with_regime(truth),
                         predicted=with_regime(predicted), transport_mse=float("nan"), residence_mse=float("nan"),
                         stripes_truth=np.empty(0), stripes_predicted=np.empty(0))
