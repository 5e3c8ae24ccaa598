"""Refilling-hopper datagen (`data=hopper_refill`): the draining hopper's pipeline (manifest, parameter table,
characterization, resume, splits) with the refilling run, the ragged refill store and refill metrics."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from neuraldem.data.manifest import SimRecord
from neuraldem.data.schema import sha256
from neuraldem.datagen.driver import fresh_dir
from neuraldem.scenes.hopper.dataset.datagen import HopperPipeline
from neuraldem.scenes.hopper_refill.solver import RefillSettings, RefillTrajectory, fill_levels, run_refill
from neuraldem.scenes.hopper_refill.store import RefillFile, write_refill_file


def refill_run_metrics(traj: RefillTrajectory, band_start: float) -> dict[str, float]:
    """Ground-truth scalars of one refilling run for the manifest (particle counts; the field-based scores
    against a model are in neuraldem.scenes.hopper_refill.metrics)."""
    levels = fill_levels(traj)
    steady = levels[traj.times >= band_start]
    left = np.isfinite(traj.exit_times)
    residence = traj.exit_times[left] - traj.insert_times[left]
    refilled = traj.insert_times > 0
    duration = float(traj.times[-1])
    return {
        "duration": duration,
        "level_min": float(steady.min()) if steady.size else float("nan"),
        "level_max": float(steady.max()) if steady.size else float("nan"),
        "level_mean": float(steady.mean()) if steady.size else float("nan"),
        # exits per second as a fraction of N0, over the second half of the run (past the start-up)
        "outflow_rate": float(np.sum(left & (traj.exit_times >= duration / 2)) / max(duration / 2, 1e-9)
                              / max(traj.n_initial, 1)),
        "n_refilled": int(refilled.sum()),
        "exit_residence_median": float(np.median(residence)) if residence.size else float("nan"),
        "exit_residence_p90": float(np.quantile(residence, 0.9)) if residence.size else float("nan"),
        "refilled_exit_fraction": float(np.mean(refilled[left])) if left.any() else float("nan"),
    }


@dataclass
class RefillPipeline(HopperPipeline):
    kind: str = "hopper_refill"

    def __post_init__(self) -> None:
        super().__post_init__()
        self.refill = RefillSettings.from_config(self.cfg.refill, "data.refill")
        self.refill.validate("data.refill", self.scene)

    def scene_record(self) -> dict[str, Any]:
        return {**super().scene_record(), "refill": self.refill.as_dict()}

    def _simulate(self, rec: SimRecord) -> None:
        p = rec.params
        workdir = fresh_dir(self.dataset_dir / "runs" / rec.sim_id)
        result = run_refill(self.scene, self.refill, p["alpha"], p["mu_s"], p["mu_r"], workdir, rec.index)
        rec.cost.update({k: float(v) for k, v in result.diagnostics.items() if k in
                         ("cpu_s", "wall_s", "max_rss_mb", "particle_steps")})
        rec.diagnostics.update({k: v for k, v in result.diagnostics.items() if k in
                                ("ended_by", "n_exited", "n_lost", "n_refilled", "level_min", "level_max")})
        rec.status, rec.reason = result.status, result.reason
        if result.trajectory is None:
            return
        rel = f"sims/{rec.sim_id}.h5"
        (self.dataset_dir / "sims").mkdir(exist_ok=True)
        write_refill_file(self.dataset_dir / rel, rec.sim_id, result.trajectory, dict(p), self.solver_version(),
                          self.position_resolution, refill=self.refill.as_dict())
        rec.file, rec.sha256 = rel, sha256(self.dataset_dir / rel)
        with RefillFile(self.dataset_dir / rel) as f:  # metrics of the data as stored (and a validation)
            rec.metrics = refill_run_metrics(f.load(), self.refill.interval)
        if not self.keep_raw:
            for name in ("dump.txt", "exits.txt"):
                (workdir / name).unlink(missing_ok=True)
