"""Fluidized-bed datagen pipeline: run DPMFoam per (inlet velocity, packing), store fields, score, split.

Parameter table (deterministic, extendable): `n_velocities` inlet velocities drawn as a seeded 1-D Latin
hypercube over the configured range, each run with `packings_per_velocity` different random start packings
(trajectories of `duration` seconds), then the long test trajectories (`long.inlet_velocities`, each of
`long.duration` seconds, fresh packings). Asking for more simulations than that appends further batches of
new velocities. Every record's packing seed is derived from (parameters.seed, record index).

Splits: `velocity` puts whole velocities (all their packings) into train/val/test, as the paper does;
`long` lists the long trajectories in `long.part` (test; val for a long validation set). A table of long
trajectories only (`n_velocities: 0`, e.g. data=fb_small_longval) adds long statistics to a dataset without
changing its table: a model trained on fb_small is scored on it with `evaluate dataset_dir=...`.

Resume: DPMFoam writes its time directories into runs/<sim_id>; a killed datagen restarts that case from
its latest complete time directory (see neuraldem.scenes.fluidized_bed.solver.runner), converts it into
sims/<sim_id>.h5 when it is finished and then deletes the time directories (unless storage.keep_raw). A failed run
keeps its folder for inspection and starts from scratch when retried (retry_failed=true).
"""

from __future__ import annotations

import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.config import checks
from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.data.schema import sha256
from neuraldem.data.splits import random_split, too_few_warning
from neuraldem.datagen.driver import DataConfigPipeline
from neuraldem.datagen.sampling import latin_hypercube
from neuraldem.errors import ConfigError
from neuraldem.scenes.fluidized_bed.analysis.metric_settings import BedMetricSettings, settings_from_config
from neuraldem.scenes.fluidized_bed.analysis.metrics import bed_height_particles, fb_summary, lacey_from_particles
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile, write_fb_file
from neuraldem.scenes.fluidized_bed.parameters import PARAMETERS
from neuraldem.scenes.fluidized_bed.solver.runner import STATUS_FAILED, STATUS_OK, remove_time_dirs, run_fluidized_bed
from neuraldem.scenes.fluidized_bed.solver.scene import BedScene
from neuraldem.sim import openfoam

FAILED_MARKER = "FAILED"
LONG_PARTS = ("test", "val")  # where a dataset's long trajectories go (data.parameters.long.part)


@dataclass
class FieldSettings:
    kernel_sigma: float = 0.002  # [m] Gaussian kernel std of the solid fraction
    mixing_sigma: float = 0.001  # [m] Gaussian kernel std of the mixing concentration
    prior_solid_fraction: float = 1e-3  # a0 of the mixing concentration

    @classmethod
    def from_config(cls, cfg: Any, key: str) -> FieldSettings:
        s = settings_from_config(cls, cfg, key)
        checks.positive(f"{key}.kernel_sigma", s.kernel_sigma)
        checks.positive(f"{key}.mixing_sigma", s.mixing_sigma)
        checks.number(f"{key}.prior_solid_fraction", s.prior_solid_fraction, lo=0.0, hi=0.1, lo_open=True)
        return s


def coarse_to_fine_rank(i: int, n: int) -> int:
    """Position of slot i of n in a farthest-first sweep (0, n-1, the middle, then always the slot farthest
    from those already taken), so that the first k slots run spread over the whole range for every k."""
    order = [0] + ([n - 1] if n > 1 else [])
    while len(order) < n:
        order.append(max((s for s in range(n) if s not in order), key=lambda s: min(abs(s - o) for o in order)))
    return order.index(i)


def file_metrics(path: Path, settings: BedMetricSettings) -> dict[str, float]:
    """Ground-truth metrics of a stored trajectory: the field metrics (as for predictions) plus
    particle-based references (Lacey from the particles, bed height from particle heights)."""
    with BedFile(path) as f:
        alpha, mix, u = f.solid_fraction(), f.mixing(), f.fluid_velocity()
        pos = f.positions()
        vp = float(np.mean(f.particle_volumes))
        out = fb_summary(f.times, alpha, mix, u, f.grid.edges(2), f.grid.cell_volume, vp,
                         float(f.particle_volumes.sum()), **settings.as_kwargs())
        lacey_p = lacey_from_particles(pos, f.labels, f.grid.lo, f.grid.hi, f.grid.shape, settings.lacey_block,
                                       settings.lacey_min_count)
        out["lacey_particles_initial"] = float(lacey_p[0])
        out["lacey_particles_final"] = float(lacey_p[-1])
        out["bed_height_particles_mean"] = float(np.mean(bed_height_particles(pos, settings.bed_quantile)))
        inflow, outflow = f.fluxes()
        ok = np.isfinite(inflow) & np.isfinite(outflow)
        if ok.any():
            out["flux_imbalance_max"] = float(np.max(np.abs(inflow[ok] - outflow[ok]) / np.abs(inflow[ok])))
    return out


PARAMETER_KEYS = ("n_sims", "seed", "inlet_velocity", "n_velocities", "packings_per_velocity", "duration", "long")
LONG_KEYS = ("inlet_velocities", "duration", "part")


@dataclass
class BedPipeline(DataConfigPipeline):
    kind: str = "fluidized_bed"

    def __post_init__(self) -> None:
        super().__post_init__()
        c = self.cfg
        self.scene = BedScene.from_config(c.scene, "data.scene")
        p = c.parameters
        # a typo in a scene file must not be ignored (`scene`, `fields`, `metrics`: their settings classes check)
        checks.known_keys("data.parameters", p, PARAMETER_KEYS)
        checks.known_keys("data.parameters.long", p.get("long") or {}, LONG_KEYS)
        checks.known_keys("data.storage", c.get("storage") or {}, ("keep_raw",))
        self.seed = checks.positive_int("data.parameters.seed", p.seed, allow_zero=True)
        lo, hi = checks.interval("data.parameters.inlet_velocity", list(p.inlet_velocity))
        u_low, u_high = PARAMETERS.limits("inlet_velocity")
        checks.number("data.parameters.inlet_velocity[0]", lo, lo=u_low, hi=u_high, lo_open=True)
        checks.number("data.parameters.inlet_velocity[1]", hi, lo=u_low, hi=u_high)
        self.velocity_range = (lo, hi)
        self.n_velocities = checks.positive_int("data.parameters.n_velocities", p.n_velocities, allow_zero=True)
        self.packings = checks.positive_int("data.parameters.packings_per_velocity", p.packings_per_velocity)
        self.duration = self._duration("data.parameters.duration", p.duration)
        long = p.get("long") or {}
        self.long_velocities = [checks.number(f"data.parameters.long.inlet_velocities[{i}]", v,
                                              lo=u_low, hi=u_high, lo_open=True)
                                for i, v in enumerate(long.get("inlet_velocities") or [])]
        self.long_duration = (self._duration("data.parameters.long.duration", long.get("duration"))
                              if self.long_velocities else 0.0)
        if self.long_velocities and self.long_duration <= self.duration:
            raise ConfigError(f"config value data.parameters.long.duration={self.long_duration} is invalid: must "
                              f"be longer than data.parameters.duration={self.duration}")
        self.long_part = checks.one_of("data.parameters.long.part", long.get("part", "test"), LONG_PARTS)
        if self.n_velocities == 0 and not self.long_velocities:
            raise ConfigError("config value data.parameters.n_velocities=0 is invalid: a table without regular "
                              "velocities needs long trajectories (set data.parameters.long.inlet_velocities, "
                              "or n_velocities >= 1)")
        self.fields = FieldSettings.from_config(c.get("fields"), "data.fields")
        self.metrics = BedMetricSettings.from_config(c.get("metrics"), "data.metrics")
        half, bx = self.scene.cells[0] / 2, self.metrics.lacey_block[0]
        if half != int(half) or int(half) % bx:
            raise ConfigError(f"config value data.metrics.lacey_block[0]={bx} is invalid: Lacey sample cells must "
                              f"tile each half of the {self.scene.cells[0]} cells in x (so that the initial "
                              "left/right split scores 0); use an even data.scene.cells[0] and a divisor of its "
                              "half (override it, e.g. data.metrics.lacey_block=[1,1,2])")
        self.keep_raw = bool(c.storage.keep_raw)
        self._existing = 0
        self._solver_version: str | None = None

    def _duration(self, key: str, value: Any) -> float:
        d = checks.positive(key, value)
        if not checks.is_multiple(d, self.scene.snapshot_interval):
            raise ConfigError(f"config value {key}={value} is invalid: must be a multiple of "
                              f"data.scene.snapshot_interval={self.scene.snapshot_interval} "
                              f"(override it, e.g. {key}=...)")
        return d

    # ---- manifest records
    def scene_record(self) -> dict[str, Any]:
        return {"fluidized_bed": self.scene.as_dict(),
                "fields": asdict(self.fields)}

    def solver_record(self) -> dict[str, str]:
        return {"name": "OpenFOAM DPMFoam", "version": self.solver_version()}

    def solver_version(self) -> str:
        if self._solver_version is None:
            self._solver_version = openfoam.foam_version()
        return self._solver_version

    def parameter_record(self) -> dict[str, Any]:
        return {"names": ["inlet_velocity", "packing", "duration"],
                "ranges": {"inlet_velocity": list(self.velocity_range)}, "sampling": "latin_hypercube",
                "seed": self.seed, "n_velocities": self.n_velocities, "packings_per_velocity": self.packings,
                "duration": self.duration,
                "long": {"inlet_velocities": self.long_velocities, "duration": self.long_duration,
                         "part": self.long_part},
                "minimum_fluidization_velocity_wen_yu": self.scene.minimum_fluidization_velocity,
                "metrics": self.metric_record()}

    def metric_record(self) -> dict[str, Any]:
        return {"lacey_block": list(self.metrics.lacey_block), "lacey_min_count": self.metrics.lacey_min_count,
                "bed_quantile": self.metrics.bed_quantile, "bubble_threshold": self.metrics.bubble_threshold}

    def prepare(self, m: Manifest) -> None:
        """New metric settings re-score the stored trajectories (the simulations stay)."""
        self._existing = len(m.simulations)
        current = self.metric_record()
        if m.parameters.get("metrics") != current:
            for rec in m.usable():
                if rec.file and (self.dataset_dir / rec.file).is_file():
                    rec.metrics = file_metrics(self.dataset_dir / rec.file, self.metrics)
            m.parameters["metrics"] = current

    def incomplete(self, record: SimRecord) -> bool:
        return False

    def run_order(self, todo: list[SimRecord], m: Manifest) -> list[SimRecord]:
        """The table is sorted by velocity; run it so that any finished part can be trained and evaluated:
        first packing of every velocity, the held-out (test) velocities first and the others in a
        coarse-to-fine order over the range, then the further packings, the long test trajectories last
        (they cost ten short ones each)."""
        held_out = set(self.velocity_parts(m).get("test", []))
        return sorted(todo, key=lambda rec: self._run_rank(rec, held_out))

    def _run_rank(self, rec: SimRecord, held_out: set[str]) -> tuple[int, int, int, int]:
        if rec.params["duration"] > self.duration:
            return (1, 0, 0, rec.index)
        velocity_slot = (rec.index // self.packings) % self.n_velocities
        return (0, int(rec.params["packing"]), 0 if _velocity_key(rec) in held_out else 1,
                coarse_to_fine_rank(velocity_slot, self.n_velocities))

    def parameter_sequence(self, count: int) -> list[dict[str, float]]:
        """The first `count` entries of the deterministic parameter table (module docstring)."""
        out: list[dict[str, float]] = []
        if self.n_velocities == 0:  # long trajectories only: the table cannot grow
            if count > len(self.long_velocities):
                raise ConfigError(f"config value n_sims={count} is invalid: data.parameters.n_velocities=0 leaves "
                                  f"{len(self.long_velocities)} long trajectories (set n_sims="
                                  f"{len(self.long_velocities)} or add data.parameters.long.inlet_velocities)")
            return [self._long_params(v) for v in self.long_velocities][:count]
        batch = 0
        while len(out) < count:
            velocities = latin_hypercube({"inlet_velocity": self.velocity_range}, self.n_velocities, self.seed,
                                         batch)
            for v in sorted(x["inlet_velocity"] for x in velocities):
                out += [{"inlet_velocity": v, "packing": float(j), "duration": self.duration}
                        for j in range(self.packings)]
            if batch == 0:
                out += [self._long_params(v) for v in self.long_velocities]
            batch += 1
        return out[:count]

    def _long_params(self, velocity: float) -> dict[str, float]:
        return {"inlet_velocity": float(velocity), "packing": 0.0, "duration": self.long_duration}

    def new_parameters(self, n: int, batch: int) -> list[dict[str, float]]:
        return self.parameter_sequence(self._existing + n)[self._existing:]

    # ---- one simulation
    def packing_seed(self, rec: SimRecord) -> int:
        return packing_seed(self.seed, rec.index)

    def run(self, rec: SimRecord) -> SimRecord:
        workdir = self.dataset_dir / "runs" / rec.sim_id
        if (workdir / FAILED_MARKER).exists():  # a retried failure starts from scratch
            shutil.rmtree(workdir)
        p = rec.params
        result = run_fluidized_bed(self.scene, p["inlet_velocity"], p["duration"], workdir, self.packing_seed(rec))
        rec.cost = dict(result.cost)
        rec.diagnostics = {"batch": rec.diagnostics.get("batch", 0), **result.diagnostics}
        rec.status, rec.reason = result.status, result.reason
        if result.status != STATUS_OK or result.trajectory is None:
            rec.status = STATUS_FAILED
            workdir.mkdir(parents=True, exist_ok=True)
            (workdir / FAILED_MARKER).write_text(rec.reason + "\n")
            return rec
        t0 = time.perf_counter()
        rel = f"sims/{rec.sim_id}.h5"
        (self.dataset_dir / "sims").mkdir(exist_ok=True)
        write_fb_file(self.dataset_dir / rel, rec.sim_id, result.trajectory, dict(p), self.solver_version(),
                      self.fields.kernel_sigma, self.fields.mixing_sigma, self.fields.prior_solid_fraction)
        rec.file, rec.sha256 = rel, sha256(self.dataset_dir / rel)
        rec.metrics = file_metrics(self.dataset_dir / rel, self.metrics)
        rec.cost["convert_s"] = time.perf_counter() - t0
        if not self.keep_raw:
            remove_time_dirs(workdir)
        return rec

    # ---- splits
    def splits(self, m: Manifest) -> dict[str, dict[str, list[str]]]:
        usable = m.usable()
        if not usable:
            return {}
        parts = self.velocity_parts(m)
        part_of = {v: part for part, vs in parts.items() for v in vs}
        out: dict[str, dict[str, list[str]]] = {"velocity": {"train": [], "val": [], "test": []}}
        for r in usable:
            if not self.is_long(r):
                out["velocity"][part_of[_velocity_key(r)]].append(r.sim_id)
        out["long"] = {"train": [], "val": [], "test": []}
        out["long"][self.long_part] = sorted(r.sim_id for r in usable if self.is_long(r))
        m.split_info["velocity"] = {part: [float(v) for v in vs] for part, vs in parts.items()}
        return out

    def split_warning(self, n_sims: int) -> str | None:
        """One line when the table's velocities are too few for a validation and a test velocity of their own."""
        s = self.cfg.splits
        fractions = {k: checks.fraction(f"data.splits.velocity.{k}", float(v)) for k, v in s.velocity.items()}
        if self.n_velocities == 0:  # long trajectories only: no split of velocities
            return None
        return too_few_warning(self.name, self.n_velocities, fractions, "velocities", "data.splits.velocity",
                               "data.parameters.n_velocities")

    def velocity_parts(self, m: Manifest) -> dict[str, list[str]]:
        """Whole velocities per part (keys as in _velocity_key), from the full table, finished or not."""
        s = self.cfg.splits
        seed = checks.positive_int("data.splits.seed", s.seed, allow_zero=True)
        fractions = {k: checks.fraction(f"data.splits.velocity.{k}", float(v)) for k, v in s.velocity.items()}
        regular = [r for r in m.simulations if not self.is_long(r)]
        return random_split(sorted({_velocity_key(r) for r in regular}), fractions, seed)

    def is_long(self, rec: SimRecord) -> bool:
        return bool(self.long_velocities) and rec.params.get("duration", 0.0) > self.duration + 1e-9


def packing_seed(table_seed: int, index: int) -> int:
    """The start-packing seed of record `index` of a table drawn with `data.parameters.seed` = `table_seed`
    (a benchmark re-running a dataset's trajectory takes it from the manifest: `parameters.seed`)."""
    return int(np.random.SeedSequence([table_seed, index]).generate_state(1)[0])


def _velocity_key(rec: SimRecord) -> str:
    return f"{rec.params['inlet_velocity']:.6f}"
