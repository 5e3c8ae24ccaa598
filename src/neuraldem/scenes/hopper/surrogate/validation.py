"""Validate a hopper model by what users ask of it, while it trains, and pick the checkpoint by that.

The occupancy BCE says little about drainage time or outflow: a model can lower it while its soft counts drift
several % of N0 away from DEM (count bias). At each validation this callback answers every validation run
through the evaluation's own path (`ModelPredictor` -> `summarise` -> `score_answers`, the DEM side through
`DemPredictor` on the same points and times, computed once) on a fixed subset of the initial particle
positions and every `time_stride`-th time, and logs:

  val/drainage_t95_pct   drainage time t95 error [% of the mean]
  val/residual_pp        residual error [percentage points]
  val/outflow_pct        outflow rate error [%]
  val/count_bias_pct     mean signed error of the soft count [% of the points], over runs and times
  val/count_abs_pct      mean absolute error of the soft count [% of the points]
  val/practitioner_score the three errors, each divided by the accuracy aimed at (`scales`: 2x LIGGGHTS's own
                         seed spread, results/hopper/accuracy/seed_floor.md), summed; lower is better

so that `callbacks.checkpoint.monitor=val/practitioner_score` keeps the checkpoint users would want.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np

from neuraldem.config import checks
from neuraldem.errors import ConfigError
from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings, metric_times, occupied_counts
from neuraldem.scenes.hopper.analysis.scoring import dataset_metric_settings, score_answers, summarise
from neuraldem.scenes.hopper.dataset.store import HopperFile
from neuraldem.scenes.hopper.surrogate.inference import ModelPredictor
from neuraldem.scenes.hopper.surrogate.predictors import DemPredictor, TrajectoryFields

log = logging.getLogger(__name__)

# accuracy aimed at per quantity: 2x the spread of LIGGGHTS rerun with other packing seeds
# (results/hopper/accuracy/seed_floor.md)
DEFAULT_SCALES = {"drainage_t95_pct_of_mean": 4.0, "residual_mae_pp": 0.8, "outflow_rel_err_pct": 2.5}
LOGGED = {"drainage_t95_pct_of_mean": "drainage_t95_pct", "residual_mae_pp": "residual_pp",
          "outflow_rel_err_pct": "outflow_pct"}


def count_bias(truth: TrajectoryFields, pred: TrajectoryFields) -> tuple[float, float]:
    """(mean signed, mean absolute) soft-count error over the times, as a share of the points."""
    diff = (occupied_counts(pred.occupancy) - occupied_counts(truth.occupancy)) / truth.occupancy.shape[1]
    return float(np.mean(diff)), float(np.mean(np.abs(diff)))


def practitioner_score(agg: dict[str, float], scales: dict[str, float]) -> float:
    """Sum of the errors in units of their target; a missing (NaN) error counts as 10 targets."""
    return float(sum(agg[k] / s if np.isfinite(agg[k]) else 10.0 for k, s in scales.items()))


class PractitionerValidation(L.Callback):
    """Scores the validation runs as users would at every validation; see the module docstring."""

    def __init__(self, max_points: int = 2000, time_stride: int = 2, max_sims: int | None = None,
                 scales: dict[str, float] | None = None, seed: int = 0):
        key = "callbacks.practitioner_validation"
        self.max_points = checks.positive_int(f"{key}.max_points", max_points)
        self.time_stride = checks.positive_int(f"{key}.time_stride", time_stride)
        self.max_sims = None if max_sims is None else checks.positive_int(f"{key}.max_sims", max_sims)
        scales = dict(DEFAULT_SCALES if scales is None else scales)
        checks.known_keys(f"{key}.scales", scales, DEFAULT_SCALES)
        self.scales = {k: checks.positive(f"{key}.scales.{k}", float(v)) for k, v in scales.items()}
        self.seed = checks.positive_int(f"{key}.seed", seed, allow_zero=True)
        self._truth: dict[str, tuple[np.ndarray, TrajectoryFields, dict[str, float]]] = {}

    def _setup(self, trainer: L.Trainer) -> tuple[Any, HopperMetricSettings, np.ndarray]:
        dm = trainer.datamodule
        if getattr(dm, "KIND", None) != "hopper" or dm.manifest is None:
            raise ConfigError("callbacks.practitioner_validation needs a draining-hopper datamodule (data="
                              "hopper_small, hopper_tiny, ...): disable it with callbacks.practitioner_validation=null")
        settings = dataset_metric_settings(dm.manifest)
        times = metric_times(dm.norm.horizon, dm.snapshot_interval)[:: self.time_stride]
        return dm, settings, times

    def _points(self, path: Path) -> np.ndarray:
        with HopperFile(path) as f:
            points = f.initial_positions()
        if len(points) > self.max_points:
            points = points[np.sort(np.random.default_rng(self.seed).choice(len(points), self.max_points, False))]
        return points

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking:
            return
        dm, settings, times = self._setup(trainer)
        records = dm.records("val")[: self.max_sims]
        radius = dm.occupancy_radius_d * dm.particle_diameter
        dem = DemPredictor(dm.dataset_dir, radius, horizon=dm.norm.horizon)
        model = ModelPredictor(pl_module.net, dm.norm, list(dm.conditioning), device=str(pl_module.device))
        was_training = pl_module.training
        truths, answers, biases = [], [], []
        for rec in records:
            if rec.sim_id not in self._truth:
                points = self._points(dm.dataset_dir / str(rec.file))
                ft = dem.fields(rec, times, points)
                self._truth[rec.sim_id] = (points, ft, summarise(ft, points[:, 2], settings)[0])
            points, ft, truth = self._truth[rec.sim_id]
            fp = model.fields(rec, times, points)
            truths.append(truth)
            answers.append(summarise(fp, points[:, 2], settings)[0])
            biases.append(count_bias(ft, fp))
        pl_module.train(was_training)
        agg = score_answers(truths, answers)
        values = {f"val/{LOGGED[k]}": agg[k] for k in LOGGED}
        values["val/count_bias_pct"] = 100 * float(np.mean([b[0] for b in biases]))
        values["val/count_abs_pct"] = 100 * float(np.mean([b[1] for b in biases]))
        values["val/practitioner_score"] = practitioner_score(agg, self.scales)
        for name, v in values.items():
            pl_module.log(name, v, on_step=False, on_epoch=True, batch_size=1, sync_dist=True)
        log.info("practitioner validation at step %d (%d runs): %s", trainer.global_step, len(records),
                 ", ".join(f"{k.removeprefix('val/')} {v:.3f}" for k, v in values.items()))
