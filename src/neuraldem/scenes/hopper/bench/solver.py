"""LIGGGHTS hopper runs for benchmarks: a dataset's own scene, scaled and shortened copies of it, their cost.

Every run goes through `scenes.hopper.solver.run_hopper`, the path datagen uses, so a benchmark times exactly the
simulation that made the training data. LIGGGHTS runs serially (one process, one thread).
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.config import checks
from neuraldem.data.manifest import Manifest, SimRecord, require_dataset
from neuraldem.errors import DataError
from neuraldem.scenes.hopper.dataset.store import HopperFile
from neuraldem.scenes.hopper.solver import HopperRunResult, HopperScene, run_hopper

SOLVER_THREADS = 1  # serial LIGGGHTS: one process, OMP_NUM_THREADS=1 (sim.liggghts.solver_env)


def dataset_scene(dataset_dir: Path) -> tuple[HopperScene, Manifest]:
    """The hopper scene a dataset was generated with (from its manifest), and the manifest."""
    dataset_dir = Path(dataset_dir)
    m = require_dataset(dataset_dir, dataset_dir.name)
    if m.kind != "hopper" or "hopper" not in m.scene:
        raise DataError(f"{dataset_dir}/manifest.json: kind={m.kind!r}, not a hopper dataset: pass a hopper "
                        "dataset (e.g. the hopper_small dataset dir)")
    return HopperScene.from_config(m.scene["hopper"], f"{dataset_dir}/manifest.json scene.hopper"), m


def run_scene(scene: HopperScene, params: dict[str, float], workdir: Path, index: int,
              keep: bool = False) -> HopperRunResult:
    """One simulation in a fresh `workdir` (removed afterwards unless `keep`); seeds follow `index`, so the
    dataset's simulation `index` with the dataset's scene reproduces that simulation."""
    if workdir.exists():
        shutil.rmtree(workdir)
    try:
        return run_hopper(scene, params["alpha"], params["mu_s"], params["mu_r"], workdir, index)
    finally:
        if not keep:
            shutil.rmtree(workdir, ignore_errors=True)


# ---- what the log says about the cost of each phase

@dataclass(frozen=True)
class LoopTime:
    """One LIGGGHTS `run` command: its own wall clock ('Loop time of X on P procs for S steps with A atoms')."""

    seconds: float
    steps: int
    atoms_end: int


def loop_times(log: str) -> list[LoopTime]:
    out = []
    for line in log.splitlines():
        if line.startswith("Loop time of"):
            parts = line.split()
            out.append(LoopTime(float(parts[3]), int(parts[8]), int(parts[11].rstrip(","))))
    return out


@dataclass(frozen=True)
class PhaseCost:
    """Fill + settle (outlet closed, all particles present) and the drain chunks after opening."""

    settle: LoopTime
    drain: list[LoopTime]
    n_particles: int

    @property
    def settle_particle_steps(self) -> float:
        return float(self.settle.steps * self.n_particles)

    def chunk_particle_steps(self) -> list[float]:
        """Steps x particles present per drain chunk, the count taken as linear within a chunk (the log
        gives it at the end of each)."""
        out, start = [], self.n_particles
        for chunk in self.drain:
            out.append(chunk.steps * 0.5 * (start + chunk.atoms_end))
            start = chunk.atoms_end
        return out

    @property
    def drain_particle_steps(self) -> float:
        return sum(self.chunk_particle_steps())

    @property
    def drain_seconds(self) -> float:
        return sum(c.seconds for c in self.drain)

    @property
    def drain_steps(self) -> int:
        return sum(c.steps for c in self.drain)

    def as_dict(self) -> dict[str, Any]:
        return {"settle_s": self.settle.seconds, "settle_steps": self.settle.steps,
                "settle_particle_steps": self.settle_particle_steps,
                "settle_particle_steps_per_s": self.settle_particle_steps / self.settle.seconds,
                "drain_s": self.drain_seconds, "drain_steps": self.drain_steps,
                "drain_particle_steps": self.drain_particle_steps,
                "drain_chunks": len(self.drain), "drain_particle_steps_per_s": drain_rate(self)}


def phase_cost(log: str, n_particles: int) -> PhaseCost:
    loops = loop_times(log)
    if len(loops) < 2:
        raise DataError(f"LIGGGHTS log has {len(loops)} 'Loop time' line(s); a hopper run has a settle run and "
                        "at least one drain run (did the run fail? see its log.liggghts)")
    return PhaseCost(loops[0], loops[1:], n_particles)


def drain_rate(cost: PhaseCost) -> float:
    """Particle-steps per second of LIGGGHTS's own clock in the last drain chunk: in a shortened run the
    first chunk starts the flow, the last one measures the flowing hopper (neighbour lists rebuilt often)."""
    last = cost.drain[-1]
    return cost.chunk_particle_steps()[-1] / last.seconds if last.seconds > 0 else float("nan")


# ---- scene variants for scaling

def scaled_scene(base: HopperScene, n_particles: int) -> HopperScene:
    """The same hopper shape for another particle count: diameters scaled by (N / N_base)^(1/3), so the
    packed column keeps its aspect ratio, and the settle time by the square root of that (fall time)."""
    checks.positive_int("n_particles", n_particles)
    s = (n_particles / base.n_particles) ** (1.0 / 3.0)
    scene = replace(base, n_particles=n_particles, hopper_diameter=base.hopper_diameter * s,
                    outlet_diameter=base.outlet_diameter * s, settle_time=base.settle_time * math.sqrt(s))
    scene.validate(f"scaled scene ({n_particles} particles)")
    return scene


def shortened_scene(scene: HopperScene, steps: int) -> HopperScene:
    """Fill and settle as usual, then drain for two chunks of `steps` timesteps: the first starts the flow,
    the second is the one whose rate is measured (`drain_rate`)."""
    checks.positive_int("steps", steps)
    span = round(steps * scene.material.dt, 12)
    short = replace(scene, snapshot_interval=span, stall_time=span, max_time=2 * span)
    short.validate(f"shortened scene ({steps} steps)")
    return short


# ---- how long and how full a full run drains (for extrapolation)

@dataclass(frozen=True)
class DrainProfile:
    """A full run's drain phase: its duration and the time-averaged share of particles still inside."""

    drain_time: float  # [s] from opening to the end of the run
    remaining_fraction: float  # time average of (particles inside / N0) over the drain
    source: str

    def particle_steps(self, n_particles: int, dt: float) -> float:
        return n_particles * (self.drain_time / dt) * self.remaining_fraction

    def as_dict(self) -> dict[str, Any]:
        return {"drain_time_s": self.drain_time, "remaining_fraction": self.remaining_fraction,
                "source": self.source}


def drain_profile_of_dataset(dataset_dir: Path, max_sims: int = 20) -> DrainProfile:
    """Median drain duration and remaining share over the dataset's first `max_sims` stored runs."""
    _, m = dataset_scene(dataset_dir)
    durations, fractions = [], []
    for rec in m.usable()[:max_sims]:
        with HopperFile(Path(dataset_dir) / str(rec.file)) as f:
            times = f.times
            inside = np.isfinite(f.positions()[..., 0]).mean(axis=1)
        durations.append(float(times[-1]))
        fractions.append(float(np.trapezoid(inside, times) / times[-1]) if times[-1] > 0 else 1.0)
    return DrainProfile(float(np.median(durations)), float(np.median(fractions)),
                        f"median over {len(durations)} stored runs of {dataset_dir}")


def extrapolated_full_run(n_particles: int, cost: PhaseCost, profile: DrainProfile, dt: float) -> dict[str, Any]:
    """A full run's solver seconds: the settle phase as measured plus the drain phase extrapolated as
    (particle-steps of a full drain) / (measured drain particle-steps per second)."""
    drain_s = profile.particle_steps(n_particles, dt) / drain_rate(cost)
    return {"settle_s_measured": cost.settle.seconds, "drain_s_extrapolated": drain_s,
            "full_run_s_extrapolated": cost.settle.seconds + drain_s}


def split_records(m: Manifest, split: str = "random", part: str = "test") -> list[SimRecord]:
    """The simulations of a split part (falling back to every usable one when the part is empty)."""
    ids = m.splits.get(split, {}).get(part, [])
    return [m.record(i) for i in ids] or m.usable()
