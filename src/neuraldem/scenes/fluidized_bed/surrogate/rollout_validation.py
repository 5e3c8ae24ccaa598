"""Validate a fluidized-bed model by what it is used for, a rollout, while it trains.

The one-step validation loss says little about a 3000-step rollout: on 29 fb_small trajectories the
checkpoint with the best one-step loss (step 500 of 1500) drifted 4.9 % in mass over 10x the training
horizon. At each validation this callback rolls the model out from the first snapshot of one validation
trajectory per inlet velocity and scores it against CFD-DEM with the evaluation's own functions
(`scenes.fluidized_bed.evaluation.compare`). It logs, averaged over the velocities:

  val/rollout_sf_mean_rel_l2   rel. L2 of the per-cell time mean of the solid fraction
  val/rollout_sf_std_rel_l2    the same for its time std (a bed that stops bubbling scores badly)
  val/rollout_lacey_mae        mean |Lacey(pred) - Lacey(CFD-DEM)| over the window
  val/rollout_mass_drift       max_t |V(t)/V(0) - 1| of the total solid volume (a fraction)
  val/rollout_score            their sum (+ DIVERGENCE_PENALTY per diverged rollout); lower is better

so that `callbacks.checkpoint.monitor=val/rollout_score` keeps the checkpoint that rolls out best.

`reference=pooled` scores each rollout (then `steps` long, beyond the trajectory if asked: e.g. 3000) against
every CFD-DEM run at its velocity together instead (`evaluation.compare_pooled`: long-time statistics, Lacey
against the mean curve): the choice to make when what matters is the statistics of a long rollout, at the
cost of `steps` model steps per validation velocity.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np

from neuraldem.config import checks
from neuraldem.data.manifest import SimRecord
from neuraldem.errors import ConfigError
from neuraldem.scenes.fluidized_bed.analysis.evaluation import (
    FieldSeries,
    compare,
    compare_pooled,
    held_out,
    mass,
    pooled_reference,
)
from neuraldem.scenes.fluidized_bed.dataset.report import metric_settings
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.rollout import DEFAULT_INIT_SNAPSHOT, ModelStepper, initial_state, rollout

log = logging.getLogger(__name__)

DIVERGENCE_PENALTY = 10.0
SCORE_TERMS = ("sf_mean_rel_l2", "sf_std_rel_l2", "lacey_mae", "mass_drift")


REFERENCES = ("trajectory", "pooled")


def score_rollout(pred: FieldSeries, truth: FieldSeries, settings: dict[str, Any], diverged: bool) -> dict[str, float]:
    """The score terms of one rollout against its CFD-DEM trajectory (statistics over the common window)."""
    c = compare(pred, truth, settings)
    return _total({"sf_mean_rel_l2": c["rel_l2"]["solid_fraction_mean"],
                   "sf_std_rel_l2": c["rel_l2"]["solid_fraction_std"], "lacey_mae": c["lacey"]["mae"],
                   "mass_drift": c["mass"]["max_drift_pct"] / 100.0}, diverged)


def score_pooled(pred: FieldSeries, reference: list[FieldSeries], settings: dict[str, Any], sims: list[str],
                 diverged: bool) -> dict[str, float]:
    """The score terms of one (whole) rollout against every CFD-DEM run at its velocity together."""
    q = compare_pooled(pred, reference, settings, sims)
    return _total({"sf_mean_rel_l2": q["rel_l2"]["solid_fraction_mean"],
                   "sf_std_rel_l2": q["rel_l2"]["solid_fraction_std"], "lacey_mae": q["lacey_mae"],
                   "mass_drift": mass(pred)["max_drift_pct"] / 100.0}, diverged)


def _total(terms: dict[str, float], diverged: bool) -> dict[str, float]:
    terms = {k: float(v) if np.isfinite(v) else DIVERGENCE_PENALTY for k, v in terms.items()}
    terms["score"] = sum(terms[k] for k in SCORE_TERMS) + (DIVERGENCE_PENALTY if diverged else 0.0)
    return terms


class RolloutValidation(L.Callback):
    """Short rollouts of the validation velocities at every validation; see the module docstring."""

    def __init__(self, steps: int = 300, max_trajectories: int | None = None, part: str = "val", seed: int = 0,
                 reference: str = "trajectory"):
        self.steps = checks.positive_int("callbacks.rollout_validation.steps", steps)
        self.reference = checks.one_of("callbacks.rollout_validation.reference", reference, REFERENCES)
        if max_trajectories is not None:
            checks.positive_int("callbacks.rollout_validation.max_trajectories", max_trajectories)
        self.max_trajectories = max_trajectories
        self.part = checks.one_of("callbacks.rollout_validation.part", part, ("val", "test"))
        self.seed = checks.positive_int("callbacks.rollout_validation.seed", seed, allow_zero=True)

    def _trajectories(self, trainer: L.Trainer) -> list[SimRecord]:
        dm = trainer.datamodule
        manifest = getattr(dm, "manifest", None)
        if manifest is None or not hasattr(dm, "dataset_dir"):
            raise ConfigError("callbacks.rollout_validation needs a fluidized-bed datamodule (data=fb_small, "
                              "fb_tiny, ...): disable it with callbacks.rollout_validation=null")
        records = held_out(manifest, dm.split, self.part, self.max_trajectories)
        return [r for r in records if r.params.get("duration", 0.0) <= dm.norm.horizon_steps * dm.norm.dt + 1e-9]

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking:
            return
        trajectories = self._trajectories(trainer)
        if not trajectories:
            return
        was_training = pl_module.training
        settings = metric_settings(trainer.datamodule.manifest)
        rows = []
        dm = trainer.datamodule
        pooled = self.reference == "pooled"
        for rec in trajectories:
            stepper = ModelStepper(pl_module, float(rec.params["inlet_velocity"]), self.seed, str(pl_module.device))
            with BedFile(Path(dm.dataset_dir) / str(rec.file)) as f:
                truth = FieldSeries.from_dataset_file(f).since(DEFAULT_INIT_SNAPSHOT)
                steps = self.steps if pooled else min(self.steps, f.n_snapshots - 1 - DEFAULT_INIT_SNAPSHOT)
                r = rollout(stepper, initial_state(f, DEFAULT_INIT_SNAPSHOT), steps, progress=False)
            pred = FieldSeries(r.times, r.solid_fraction.astype(np.float64), r.fluid_velocity.astype(np.float64),
                               r.mixing.astype(np.float64), truth.grid, truth.particle_volume,
                               truth.total_particle_volume)
            diverged = r.diverged_at is not None
            if pooled:
                ids, reference = pooled_reference(dm.manifest, Path(dm.dataset_dir), rec, DEFAULT_INIT_SNAPSHOT)
                rows.append(score_pooled(pred, reference, settings, ids, diverged))
            else:
                rows.append(score_rollout(pred, truth.window(steps + 1), settings, diverged))
        pl_module.train(was_training)
        means = {k: float(np.mean([row[k] for row in rows])) for k in (*SCORE_TERMS, "score")}
        for k, v in means.items():
            name = "val/rollout_score" if k == "score" else f"val/rollout_{k}"
            pl_module.log(name, v, on_step=False, on_epoch=True, batch_size=1, sync_dist=True)
        log.info("rollout validation at step %d (%d velocities, %d steps): %s", trainer.global_step, len(rows),
                 self.steps, ", ".join(f"{k} {v:.4f}" for k, v in means.items()))
