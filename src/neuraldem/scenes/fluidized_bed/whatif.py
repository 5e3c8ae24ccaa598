"""What-if answers for a fluidized bed at an inlet velocity nobody has simulated: the numbers from the scalar
GP, the fields from a rollout of the field model, and (to check either) DPMFoam itself at the same velocity.

The answers are three numbers a bed operator reads, all computed by `bed_answers` from grid fields, the same
function for CFD-DEM files and rollouts, over the same window (snapshot 1 to the dataset's trajectory
duration: snapshot 0 has no last displacement, which the model never sees as input):
- bed height: time mean of the height below which 95 % of the solid volume lies [m];
- bubble fraction: time mean of the void share of the bed volume (cells below the bed surface with solid
  fraction < 0.15);
- Lacey index after `lacey_time` (1 s for fb_small): how far the left/right tagged solids have mixed.
The dataset's metric settings (Lacey sample cells, bed quantile, void threshold) travel with the model.

A rollout needs a first state (particles and fields). The shipped model carries snapshot 1 of a few training
trajectories (`InitialStates`, a small .npz); a what-if starts from the one nearest in inlet velocity, and the
stored test errors were measured along this same path.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes.fluidized_bed.analysis.metrics import bed_height, bubble_fraction, lacey_from_fields
from neuraldem.sim.foam_reader import BoxGrid

if TYPE_CHECKING:  # torch (rollout) and scipy (datagen) load only when fields are asked for: the GP answers fast
    from neuraldem.scenes.fluidized_bed.analysis.metric_settings import BedMetricSettings
    from neuraldem.scenes.fluidized_bed.surrogate.rollout import BedState

START_SNAPSHOT = 1
TARGETS = ("bed_height", "bubble_fraction", "lacey")
# what each answer can be at all: a GP's mean and interval ends, and a rollout's answer, are clipped to it (a Lacey
# index is 0 for segregated and 1 for randomly mixed material; a fraction lies in [0, 1]; a height is >= 0)
TARGET_RANGE = {"bed_height": (0.0, math.inf), "bubble_fraction": (0.0, 1.0), "lacey": (0.0, 1.0)}


def clipped(values: dict[str, float]) -> dict[str, float]:
    """Answers inside their physical range (`TARGET_RANGE`); NaN stays NaN."""
    return {k: (float(min(max(v, TARGET_RANGE[k][0]), TARGET_RANGE[k][1])) if k in TARGET_RANGE and v == v else v)
            for k, v in values.items()}


def load_gp(path: Path) -> Any:
    """A shipped bed GP answering inside the physical ranges (`TARGET_RANGE`, also for GPs stored before a range
    was tightened)."""
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess

    gp = ArrayGaussianProcess.load_npz(path)
    gp.target_range.update(TARGET_RANGE)
    return gp


def check_fluidized(scene_record: dict[str, Any], velocity: float, key: str = "inlet_velocity") -> None:
    """Below the minimum fluidization velocity the bed stays a fixed packing, which no bed model was trained on
    and the answers (bubbles, mixing) do not describe: refused with the velocity to ask at instead."""
    from neuraldem.scenes.fluidized_bed.solver.scene import BedScene

    u_mf = BedScene.from_config(scene_record["fluidized_bed"], "model scene").minimum_fluidization_velocity
    if velocity < u_mf:
        raise ConfigError(f"{key}={velocity:g} m/s is below this bed's minimum fluidization velocity "
                          f"({u_mf:.2f} m/s, Wen & Yu): the bed stays a fixed packing, with no bubbles and no "
                          "mixing, and no model here was trained on one", f"ask at {key} >= {u_mf:.2f}")


def quantities(lacey_time: float) -> dict[str, tuple[str, str, float]]:
    """answer key -> (label, unit, scale to the unit)."""
    return {"bed_height": ("bed height (mean)", "mm", 1000.0),
            "bubble_fraction": ("bubble fraction (mean)", "%", 100.0),
            "lacey": (f"Lacey index after {lacey_time:g} s", "", 1.0)}


def format_answer(key: str, v: float | None, q: dict[str, tuple[str, str, float]]) -> str:
    """A value in its unit as `predict fb` and the explorer show it ('-' when there is none)."""
    return "-" if v is None or not np.isfinite(v) else f"{q[key][2] * v:.{3 if key == 'lacey' else 2}f}"


def answer_label(key: str, q: dict[str, tuple[str, str, float]]) -> str:
    name, unit, _ = q[key]
    return f"{name}{f' [{unit}]' if unit else ''}"


@dataclass(frozen=True)
class AnswerWindow:
    """Where the answers are read: snapshots START_SNAPSHOT .. duration, Lacey at lacey_time."""

    duration: float  # [s] the training trajectories' stored duration
    lacey_time: float  # [s]
    dt: float  # [s] snapshot interval

    @property
    def steps(self) -> int:
        """Rollout steps from snapshot START_SNAPSHOT to the end of the window."""
        return round(self.duration / self.dt) - START_SNAPSHOT

    def as_dict(self) -> dict[str, float]:
        return {"duration": self.duration, "lacey_time": self.lacey_time, "dt": self.dt}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> AnswerWindow:
        return cls(float(d["duration"]), float(d["lacey_time"]), float(d["dt"]))


@dataclass
class BedCurves:
    times: np.ndarray
    bed_height: np.ndarray
    bubble_fraction: np.ndarray
    lacey: np.ndarray

    def as_series(self) -> dict[str, np.ndarray]:
        """In the form `plots.plot_curves` reads."""
        return {"time": self.times, "bed_height": self.bed_height, "bubble_fraction": self.bubble_fraction,
                "lacey_field": self.lacey}


def bed_curves(times: np.ndarray, solid_fraction: np.ndarray, mixing: np.ndarray, grid: BoxGrid,
               particle_volume: float, settings: BedMetricSettings) -> BedCurves:
    h = bed_height(solid_fraction, grid.edges(2), settings.bed_quantile)
    return BedCurves(
        times=np.asarray(times, dtype=np.float64), bed_height=h,
        bubble_fraction=bubble_fraction(solid_fraction, grid.edges(2), h, settings.bubble_threshold),
        lacey=np.array([lacey_from_fields(a[None], m[None], grid.cell_volume, particle_volume,
                                          settings.lacey_block, settings.lacey_min_count)[0]
                        for a, m in zip(solid_fraction, mixing, strict=True)]))


def bed_answers(c: BedCurves, window: AnswerWindow) -> dict[str, float]:
    """The three answers from curves that cover the window (the same for CFD-DEM and rollouts)."""
    keep = c.times <= window.duration + 1e-9
    if not keep.any() or c.times[keep][-1] < window.lacey_time - 1e-9:
        return {t: float("nan") for t in TARGETS}
    return {"bed_height": float(np.nanmean(c.bed_height[keep])),
            "bubble_fraction": float(np.nanmean(c.bubble_fraction[keep])),
            "lacey": float(np.interp(window.lacey_time, c.times[keep], c.lacey[keep]))}


def file_answers(path: Path, settings: BedMetricSettings, window: AnswerWindow) -> tuple[dict[str, float], BedCurves]:
    """CFD-DEM's answers: a stored trajectory's fields from snapshot START_SNAPSHOT on."""
    from neuraldem.scenes.fluidized_bed.dataset.store import BedFile  # scipy: not on the GP's path

    with BedFile(path) as f:
        sl = slice(START_SNAPSHOT, None)
        c = bed_curves(f.times[sl], f.solid_fraction(sl), f.mixing(sl), f.grid, float(np.mean(f.particle_volumes)),
                       settings)
    return bed_answers(c, window), c


# ---- shipped first states
STATE_FIELDS = ("positions", "displacement", "fluid_velocity", "solid_fraction", "mixing", "solids_flux")


@dataclass
class InitialStates:
    """Snapshot START_SNAPSHOT of a few trajectories (particles padded with NaN to one count), with their
    inlet velocities, the grid and the particle volumes: what a what-if rollout starts from."""

    velocities: np.ndarray  # (K,)
    sim_ids: list[str]
    times: np.ndarray  # (K,)
    arrays: dict[str, np.ndarray]  # STATE_FIELDS, each (K, ...)
    particle_volumes: np.ndarray  # (K, N) [m^3], NaN where padded
    grid: BoxGrid

    @classmethod
    def from_files(cls, paths: list[Path]) -> InitialStates:
        from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
        from neuraldem.scenes.fluidized_bed.surrogate.rollout import initial_state

        states, vols, velocities, ids, grid = [], [], [], [], None
        for p in paths:
            with BedFile(p) as f:
                s = initial_state(f, START_SNAPSHOT)
                present = np.isfinite(f.positions(START_SNAPSHOT)).all(axis=1)
                vols.append(f.particle_volumes[present])
                velocities.append(f.inlet_velocity)
                ids.append(f.sim_id)
                if grid is None:
                    grid = f.grid
                elif list(f.grid.shape) != list(grid.shape):
                    raise DataError(f"{p}: grid {list(f.grid.shape)} differs from {list(grid.shape)} of {paths[0]}")
                states.append(s)
        if grid is None:
            raise DataError("no trajectory given for the initial states")
        n = max(len(v) for v in vols)

        def pad(a: np.ndarray) -> np.ndarray:
            return np.concatenate([a, np.full((n - len(a), *a.shape[1:]), np.nan)]) if len(a) < n else a

        arrays = {k: np.stack([pad(getattr(s, k)) if k in ("positions", "displacement") else getattr(s, k)
                               for s in states]).astype(np.float32) for k in STATE_FIELDS}
        return cls(np.array(velocities), ids, np.array([s.time for s in states]), arrays,
                   np.stack([pad(v) for v in vols]), grid)

    def save_npz(self, path: Path) -> Path:
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(tmp, velocities=self.velocities, sim_ids=np.array(self.sim_ids), times=self.times,
                            particle_volumes=self.particle_volumes, grid_lo=np.asarray(self.grid.lo),
                            grid_hi=np.asarray(self.grid.hi), grid_shape=np.asarray(self.grid.shape),
                            **self.arrays)
        tmp.replace(path)
        return path

    @classmethod
    def load_npz(cls, path: Path) -> InitialStates:
        try:
            with np.load(path, allow_pickle=False) as z:
                d = {k: z[k] for k in z.files}
            grid = BoxGrid(tuple(d["grid_lo"]), tuple(d["grid_hi"]), tuple(int(n) for n in d["grid_shape"]))
            return cls(d["velocities"], [str(s) for s in d["sim_ids"]], d["times"], {k: d[k] for k in STATE_FIELDS},
                       d["particle_volumes"], grid)
        except Exception as e:  # truncated or foreign: one message
            raise DataError(f"initial-state file {path} is damaged or not a saved set of bed states "
                            f"({type(e).__name__})", "rebuild it (neuraldem release)") from None

    def nearest(self, velocity: float) -> tuple[BedState, float, str]:
        """The state nearest in inlet velocity (padding dropped), its particles' mean volume and its name."""
        from neuraldem.scenes.fluidized_bed.surrogate.rollout import BedState

        k = int(np.argmin(np.abs(self.velocities - velocity)))
        ok = np.isfinite(self.arrays["positions"][k]).all(axis=1)
        a = {name: self.arrays[name][k].astype(np.float64) for name in STATE_FIELDS}
        state = BedState(time=float(self.times[k]), positions=a["positions"][ok], displacement=a["displacement"][ok],
                        fluid_velocity=a["fluid_velocity"], solid_fraction=a["solid_fraction"], mixing=a["mixing"],
                        solids_flux=a["solids_flux"])
        vols = self.particle_volumes[k][np.isfinite(self.particle_volumes[k])]
        return state, float(vols.mean()), f"{self.sim_ids[k]} ({self.velocities[k]:.3g} m/s) snapshot {START_SNAPSHOT}"


# ---- the field model's answer
@dataclass
class FieldAnswer:
    rollout: Any  # rollout.Rollout
    curves: BedCurves
    summary: dict[str, float]
    seconds: float
    start: str
    extrapolation: dict[str, list[float]]
    runtime: str = "torch"  # what stepped the net (`ModelStepper`)


def field_answer(module: Any, states: InitialStates, velocity: float, settings: BedMetricSettings,
                 window: AnswerWindow, seed: int = 0, particles_every: int = 10,
                 runtime: str = "auto", threads: int = 1, gate: Callable[[], None] | None = None) -> FieldAnswer:
    """Roll the model out over the answer window from the shipped state nearest in velocity; read the answers.
    `runtime`: what steps the net (auto: ONNX Runtime where installed, equal to torch to round-off); `threads`:
    its threads (one is fastest for the shipped model on a 2-core CPU: 0.31 s per simulated second against 0.61 s
    on two, results/fluidized_bed/speed/fb_speed.md); `gate`: called before every step (the explorer's pauses,
    which do not change the rollout)."""
    from neuraldem.bench.timing import torch_threads
    from neuraldem.scenes.fluidized_bed.surrogate.rollout import GatedStepper, ModelStepper, rollout  # torch

    t0 = time.perf_counter()
    norm = module.norm
    state, particle_volume, start = states.nearest(velocity)
    with torch_threads(threads):
        stepper = ModelStepper(module, velocity, seed, runtime=runtime)
        r = rollout(stepper if gate is None else GatedStepper(stepper, gate), state, window.steps,
                    particles_every=particles_every, progress=False)
    curves = bed_curves(r.times, r.solid_fraction.astype(np.float64), r.mixing.astype(np.float64), states.grid,
                        particle_volume, settings)
    summary = bed_answers(curves, window)
    if r.diverged_at is not None:
        summary = {t: float("nan") for t in TARGETS}
    extrapolation = {} if norm.in_trained_range(velocity) else \
        {"inlet_velocity": [float(velocity), norm.velocity_lo, norm.velocity_hi]}
    return FieldAnswer(r, curves, summary, time.perf_counter() - t0, start, extrapolation, stepper.runtime)


# ---- DPMFoam on the same velocity
@dataclass
class SolverAnswer:
    status: str
    reason: str
    answers: dict[str, float]
    seconds: float
    curves: BedCurves | None
    file: Path | None


def dpmfoam_answer(scene_record: dict[str, Any], velocity: float, workdir: Path, settings: BedMetricSettings,
                   window: AnswerWindow, seed: int = 0) -> SolverAnswer:
    """DPMFoam at `velocity` for the window's duration, stored and scored like every dataset run."""
    from neuraldem.scenes.fluidized_bed.dataset.datagen import FieldSettings
    from neuraldem.scenes.fluidized_bed.dataset.store import write_fb_file
    from neuraldem.scenes.fluidized_bed.solver.runner import run_fluidized_bed
    from neuraldem.scenes.fluidized_bed.solver.scene import BedScene
    from neuraldem.sim import openfoam

    scene = BedScene.from_config(scene_record["fluidized_bed"], "model scene")
    fields = FieldSettings.from_config(scene_record.get("fields"), "model scene fields")
    t0 = time.perf_counter()
    result = run_fluidized_bed(scene, velocity, window.duration, workdir / "case", seed)
    if result.trajectory is None or result.status != "ok":
        return SolverAnswer(result.status, result.reason, {}, time.perf_counter() - t0, None, None)
    path = workdir / "trajectory.h5"
    write_fb_file(path, "whatif", result.trajectory, {"inlet_velocity": velocity, "duration": window.duration},
                  openfoam.foam_version(), fields.kernel_sigma, fields.mixing_sigma, fields.prior_solid_fraction)
    seconds = time.perf_counter() - t0
    answers, curves = file_answers(path, settings, window)
    return SolverAnswer(result.status, "", answers, seconds, curves, path)
