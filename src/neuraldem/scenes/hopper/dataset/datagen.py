"""Hopper datagen pipeline: characterize the material, run the draining hopper, store, score."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from neuraldem.config import checks
from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.data.schema import sha256
from neuraldem.data.splits import auto_theta_band, band_split, random_split, too_few_warning
from neuraldem.datagen.driver import DataConfigPipeline, fresh_dir, simulation_done
from neuraldem.datagen.sampling import latin_hypercube
from neuraldem.errors import ConfigError, SolverError
from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings, hopper_summary, metric_times
from neuraldem.scenes.hopper.dataset.fields import trajectory_fields_at
from neuraldem.scenes.hopper.dataset.store import HopperFile, write_hopper_file
from neuraldem.scenes.hopper.parameters import PARAMETERS
from neuraldem.scenes.hopper.solver import (
    STATUS_FAILED,
    HopperScene,
    HopperTrajectory,
    run_hopper,
)
from neuraldem.scenes.hopper.surrogate.predictors import hold_final_state
from neuraldem.sim import liggghts
from neuraldem.sim.material import Material


@dataclass
class MetricFields:
    """The fields a run's metrics are read from: occupancy and transport at the initial positions on the
    metric time grid."""

    times: np.ndarray  # (T,)
    points: np.ndarray  # (Q, 3) the initial positions
    occupancy: np.ndarray  # (T, Q)
    transport: np.ndarray  # (T, Q, 3)


def metric_fields(traj: HopperTrajectory, diameter: float, settings: HopperMetricSettings,
                  horizon: float | None = None) -> MetricFields:
    """Fields at the initial positions on the metric time grid (0 .. `horizon`, the scene's max_time; default
    the run's own end), a run that ended earlier holding its final state."""
    points = traj.positions[0]
    horizon = float(traj.times[-1]) if horizon is None else max(float(horizon), float(traj.times[-1]))
    interval = float(np.round(traj.times[1] - traj.times[0], 9)) if len(traj.times) > 1 else horizon or 1.0
    times = metric_times(horizon, interval)
    positions = hold_final_state(traj.positions, len(times))
    exits = np.where(np.isfinite(traj.exit_times), traj.exit_times, horizon)
    occ, transport, _ = trajectory_fields_at(points, times, positions, exits,
                                             settings.occupancy_radius_d * diameter)
    return MetricFields(times, points, occ, transport)


def trajectory_metrics(traj: HopperTrajectory, diameter: float,
                       settings: HopperMetricSettings = HopperMetricSettings(),  # noqa: B008 frozen dataclass, immutable
                       horizon: float | None = None, fields: MetricFields | None = None) -> dict[str, float]:
    """Ground-truth metrics through the same path as predictions (`metric_fields`; pass them when computed)."""
    f = fields if fields is not None else metric_fields(traj, diameter, settings, horizon)
    out = hopper_summary(f.times, f.occupancy, f.transport[..., 2], f.points[:, 2], settings)
    # direct particle counts, for reference (not available to a field surrogate)
    out["residual_fraction_particles"] = float(np.mean(~np.isfinite(traj.exit_times)))
    out["duration"] = float(traj.times[-1])
    return out


def stored_metrics(path: Path, diameter: float,
                   settings: HopperMetricSettings = HopperMetricSettings(),  # noqa: B008 frozen dataclass, immutable
                   horizon: float | None = None) -> dict[str, float]:
    """Metrics of the trajectory as stored (quantised positions), so anyone recomputing them from the
    dataset gets exactly the manifest's numbers."""
    with HopperFile(path) as f:
        return trajectory_metrics(f.load(), diameter, settings, horizon)


# the keys of the scene file's sections read here (`scene` and `metrics` are checked by their settings classes)
SECTION_KEYS = {"parameters": ("n_sims", "seed", "ranges"), "characterization": ("enabled", "shear", "heap"),
                "storage": ("position_resolution", "keep_raw")}


@dataclass
class HopperPipeline(DataConfigPipeline):
    kind: str = "hopper"

    def __post_init__(self) -> None:
        super().__post_init__()
        c = self.cfg
        for section, known in SECTION_KEYS.items():  # a typo in a scene file must not be ignored
            checks.known_keys(f"data.{section}", c.get(section) or {}, known)
        self.scene = HopperScene.from_config(c.scene, "data.scene")
        self.ranges = {}
        for k, v in c.parameters.ranges.items():
            if k not in PARAMETERS:
                raise ConfigError(f"data.parameters.ranges.{k}: unknown parameter; "
                                         f"known: {sorted(PARAMETERS.names)}")
            lo, hi = checks.interval(f"data.parameters.ranges.{k}", list(v))
            plo, phi = PARAMETERS.limits(k)
            checks.number(f"data.parameters.ranges.{k}[0]", lo, lo=plo, hi=phi)
            checks.number(f"data.parameters.ranges.{k}[1]", hi, lo=plo, hi=phi)
            self.ranges[k] = (lo, hi)
        missing = sorted(set(PARAMETERS.names) - set(self.ranges))
        if missing:
            raise ConfigError(f"data.parameters.ranges lacks {missing}")
        self.seed = checks.positive_int("data.parameters.seed", c.parameters.seed, allow_zero=True)
        char = c.characterization
        self.characterization_enabled = bool(char.enabled)
        if self.characterization_enabled:
            from neuraldem.sim.characterize import HeapSettings, ShearSettings

            self.shear = ShearSettings.from_config(char.shear, "data.characterization.shear")
            self.heap = HeapSettings.from_config(char.heap, "data.characterization.heap")
        self.position_resolution = checks.positive("data.storage.position_resolution",
                                                   c.storage.position_resolution)
        self.keep_raw = bool(c.storage.keep_raw)
        self.metrics = HopperMetricSettings.from_config(c.metrics, "data.metrics")
        self._solver_version: str | None = None

    # ---- manifest records
    def scene_record(self) -> dict[str, Any]:
        return {"hopper": self.scene.as_dict(), "position_resolution": self.position_resolution}

    def characterization_record(self) -> dict[str, Any]:
        from neuraldem.sim.characterize import CACHE_VERSION

        return json.loads(json.dumps({"shear": self.shear.as_dict(), "heap": self.heap.as_dict(),
                                      "version": CACHE_VERSION}))

    def prepare(self, m: Manifest) -> None:
        """New characterization settings invalidate the measurements, not the simulations; new metric
        definitions are recomputed from the stored files (no solver run)."""
        self.rescore(m)
        if not self.characterization_enabled:
            return
        current = self.characterization_record()
        if m.characterization is not None and m.characterization != current:
            for rec in m.simulations:
                rec.macro = {}
        m.characterization = current

    def rescore(self, m: Manifest) -> int:
        """Recompute the metrics of every stored run whose manifest entry was scored with other settings."""
        current = self.metrics.as_dict()
        stale = [r for r in m.simulations if r.file is not None and r.metrics and m.metric_settings != current
                 and (self.dataset_dir / r.file).is_file()]
        for rec in tqdm(stale, desc=f"{self.name}: rescoring with the current metric settings", unit="sim",
                        disable=not stale):
            rec.metrics = self.score(self.dataset_dir / str(rec.file))
        m.metric_settings = current
        return len(stale)

    def score(self, path: Path) -> dict[str, float]:
        return stored_metrics(path, self.scene.material.diameter, self.metrics, self.scene.max_time)

    def incomplete(self, rec: SimRecord) -> bool:
        return self.characterization_enabled and not rec.macro

    def run_order(self, todo: list[SimRecord], manifest: Manifest) -> list[SimRecord]:
        return todo  # a Latin hypercube table: any prefix already spreads over the ranges

    def solver_record(self) -> dict[str, str]:
        return {"name": "LIGGGHTS", "version": self.solver_version()}

    def solver_version(self) -> str:
        if self._solver_version is None:
            import tempfile

            with tempfile.TemporaryDirectory() as tmp:
                version, _ = liggghts.free_fall_check(Path(tmp))
            self._solver_version = version or "unknown"
        return self._solver_version

    def parameter_record(self) -> dict[str, Any]:
        return {"names": list(self.ranges), "ranges": {k: list(v) for k, v in self.ranges.items()},
                "sampling": "latin_hypercube", "seed": self.seed}

    def new_parameters(self, n: int, batch: int) -> list[dict[str, float]]:
        return latin_hypercube(self.ranges, n, self.seed, batch)

    # ---- one simulation
    def run(self, rec: SimRecord) -> SimRecord:
        if self.characterization_enabled and not rec.macro:
            self._characterize(rec)
        if rec.status != STATUS_FAILED and not simulation_done(rec, self.dataset_dir):
            self._simulate(rec)
        return rec

    def _material(self, rec: SimRecord) -> Material:
        return Material(**{**self.scene.material.as_dict(), "mu_s": rec.params["mu_s"],
                           "mu_r": rec.params["mu_r"]})

    def _characterize(self, rec: SimRecord) -> None:
        from neuraldem.sim.characterize import characterize

        try:
            char = characterize(self._material(rec), self.shear, self.heap,
                                self.dataset_dir / "characterization" / rec.sim_id, self.scene.timeout_s)
        except SolverError as err:
            rec.status, rec.reason = STATUS_FAILED, f"characterization: {err}"
            return
        rec.macro = {"theta": float(char["theta"]), "repose": float(char["repose"])}
        rec.cost["characterization_cpu_s"] = float(char.get("cpu_s", float("nan")))

    def _simulate(self, rec: SimRecord) -> None:
        p = rec.params
        workdir = fresh_dir(self.dataset_dir / "runs" / rec.sim_id)
        result = run_hopper(self.scene, p["alpha"], p["mu_s"], p["mu_r"], workdir, rec.index)
        rec.cost.update({k: float(v) for k, v in result.diagnostics.items() if k in
                         ("cpu_s", "wall_s", "max_rss_mb", "particle_steps")})
        rec.diagnostics.update({k: v for k, v in result.diagnostics.items() if k in
                                ("ended_by", "n_exited", "n_lost")})
        rec.status, rec.reason = result.status, result.reason
        if result.trajectory is None:
            return
        rel = f"sims/{rec.sim_id}.h5"
        (self.dataset_dir / "sims").mkdir(exist_ok=True)
        write_hopper_file(self.dataset_dir / rel, rec.sim_id, result.trajectory, dict(p),
                          self.solver_version(), self.position_resolution)
        rec.file, rec.sha256 = rel, sha256(self.dataset_dir / rel)
        rec.metrics = self.score(self.dataset_dir / rel)
        if not self.keep_raw:
            for name in ("dump.txt", "exits.txt"):
                (workdir / name).unlink(missing_ok=True)

    # ---- splits
    def split_warning(self, n_sims: int) -> str | None:
        """One line when `n_sims` runs are too few for a validation and a test run of their own (random split)."""
        s = self.cfg.splits
        fractions = {k: checks.fraction(f"data.splits.random.{k}", float(v)) for k, v in s.random.items()}
        return too_few_warning(self.name, n_sims, fractions, "runs", "data.splits.random", "n_sims")

    def splits(self, m: Manifest) -> dict[str, dict[str, list[str]]]:
        usable = m.usable()
        if not usable:
            return {}
        s = self.cfg.splits
        seed = checks.positive_int("data.splits.seed", s.seed, allow_zero=True)
        fractions = {k: checks.fraction(f"data.splits.random.{k}", float(v)) for k, v in s.random.items()}
        out = {"random": random_split([r.sim_id for r in usable], fractions, seed)}
        alpha_band = checks.interval("data.splits.band.alpha", list(s.band.alpha))
        thetas = np.array([r.macro["theta"] for r in usable if "theta" in r.macro])
        theta_band = None
        if len(thetas) == len(usable):
            theta_band = (checks.interval("data.splits.band.theta", list(s.band.theta))
                          if s.band.theta is not None else auto_theta_band(thetas, alpha_band, self.ranges["alpha"]))
        out["band"] = band_split(usable, alpha_band, theta_band,
                                 checks.fraction("data.splits.band.val", float(s.band.val)), seed)
        m.split_info["band"] = {"alpha": list(alpha_band), "theta": list(theta_band) if theta_band else None}
        return out
