"""GnsDataModule: one-step samples for the particle-based baseline (`models.gns`), from either scene's files.

A sample is one stored snapshot t of one run (hopper: `HopperFile`, fluidized bed: `BedFile`; positions are
NaN where a particle has left, i.e. crossed the hopper's sink or been lost by DPMFoam):
- nodes: the particles present at t (they are present at every earlier snapshot: none reappears);
- inputs: the last H + 1 positions t - H .. t as H finite-difference velocities (v_k = (x_k - x_{k-1}) / dt),
  the current position in particle diameters (the length unit of the graph), distances to the scene's walls,
  and the run's conditioning scalars (hopper: the scalars of the hopper datamodule without the time,
  fluidized bed: the inlet velocity);
- target: the acceleration a_t = (x_{t+1} - 2 x_t + x_{t-1}) / dt^2, masked where a particle is gone at t + 1.
Velocities and accelerations are standardised per axis with statistics of the training split only
(`GnsNormalizer`, stored in every checkpoint).

Training inputs carry random-walk noise (`noise_std`, in model units of velocity: the std of the noise on
the last velocity): independent increments along the history add up, so the noise grows with the history
index, and the positions are rebuilt from the noisy velocities. The target is corrected so that one step of
the integrator from the noisy state reaches the true next velocity: a~ = a - n_H / dt. Validation and test
samples carry no noise.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Self

import numpy as np
import torch
from torch_geometric.data import Data
from torch_geometric.loader import DataLoader as GraphLoader

from neuraldem.config import checks
from neuraldem.data.file_samples import FileSamples
from neuraldem.data.manifest import Manifest, SimRecord, require_dataset
from neuraldem.data.normalization import DictStats, scaled_scalar
from neuraldem.data.part_loaders import PartLoaders
from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.hopper.dataset.store import HopperFile
from neuraldem.scenes.hopper.solver import HopperGeometry

log = logging.getLogger(__name__)

SCENES = ("hopper", "fluidized_bed")
CONDITIONING = {"hopper": ("alpha", "mu_s", "mu_r", "theta", "repose"), "fluidized_bed": ("inlet_velocity",)}
SPLITS = {"hopper": ("random", "band"), "fluidized_bed": ("velocity",)}
N_EXTRA_WALLS = {"hopper": 2, "fluidized_bed": 0}  # hopper: distance to the cylinder and to the cone/bottom
MAX_NOISE = 1.0  # model units (one std of the training velocities)
MAX_HISTORY = 20
STD_FLOOR = 1e-3  # a channel's std is at least this share of the largest channel std


# ---- one stored run, seen as particles
class ParticleRun:
    """A stored trajectory of either scene as particles: positions (NaN = absent), times, diameters, the box
    the particles live in, and where they may leave it (the hopper's sink plane)."""

    def __init__(self, path: Path, kind: str, scene: dict[str, Any], validate: bool = True):
        self.kind = checks.one_of("scene kind", kind, SCENES)
        self.path = Path(path)
        if kind == "hopper":
            self.f: HopperFile | BedFile = HopperFile(path, validate=validate)
            g = self.f.geometry
            self.geometry: HopperGeometry | None = g
            self.diameters = np.full(self.f.n_particles, float(scene["hopper"]["material"]["diameter"]))
            self.box_lo, self.box_hi = g.box()
            self.exit_z: float | None = g.sink_z  # below the sink plane a particle has left (as in the data)
            self.labels: np.ndarray | None = None
        else:
            self.f = BedFile(path, validate=validate)
            self.geometry = None
            self.diameters = np.asarray(self.f.diameters, dtype=np.float64)
            self.box_lo, self.box_hi = np.asarray(self.f.grid.lo), np.asarray(self.f.grid.hi)
            self.exit_z = None
            self.labels = np.asarray(self.f.labels)
        self.times = np.asarray(self.f.times)

    @property
    def n_particles(self) -> int:
        return self.f.n_particles

    @property
    def n_snapshots(self) -> int:
        return self.f.n_snapshots

    @property
    def dt(self) -> float:
        return float(self.times[1] - self.times[0])

    def positions(self, t: int | slice = slice(None)) -> np.ndarray:
        return self.f.positions(t)

    def close(self) -> None:
        self.f.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def hopper_wall_distances(pos: np.ndarray, g: HopperGeometry) -> np.ndarray:
    """(N, 2) distances [m] of particle centres to the hopper's cylinder wall (R - r) and to its bottom (the
    cone, or the flat bottom, from the outlet rim (r_o, 0) to (R, h_cone) in the (r, z) plane)."""
    r = np.hypot(pos[:, 0], pos[:, 1])
    z = pos[:, 2]
    a = np.array([g.outlet_radius, 0.0])
    b = np.array([g.radius, g.cone_height])
    ab = b - a
    p = np.stack([r, z], axis=1) - a
    s = np.clip(p @ ab / (ab @ ab), 0.0, 1.0)
    cone = np.linalg.norm(p - s[:, None] * ab, axis=1)
    return np.stack([g.radius - r, cone], axis=1)


def extra_wall_distances(run: ParticleRun, pos: np.ndarray) -> np.ndarray:
    """(N, E) distances [m] to the scene's walls that are not the box's."""
    if run.geometry is not None:
        return hopper_wall_distances(pos, run.geometry)
    return np.zeros((len(pos), 0))


def random_walk_noise(rng: np.random.Generator, n: int, history: int, std: float) -> np.ndarray:
    """(n, history, 3) velocity noise: a random walk along the history whose last step has std `std`
    (independent increments of std / sqrt(history))."""
    steps = rng.standard_normal((n, history, 3)) * (std / math.sqrt(history))
    return np.cumsum(steps, axis=1)


# ---- normalisation
@dataclass
class GnsNormalizer(DictStats):
    kind: str
    length: float  # [m] the graph's length unit (mean particle diameter)
    dt: float  # [s] one step (snapshot interval)
    history: int  # velocities in the input
    conditioning: list[str]
    velocity_mean: list[float]  # [m/s] per axis
    velocity_std: list[float]
    acceleration_mean: list[float]  # [m/s^2] per axis
    acceleration_std: list[float]
    scalar_lo: dict[str, float] = field(default_factory=dict)
    scalar_hi: dict[str, float] = field(default_factory=dict)
    horizon_steps: int = 0  # steps of the longest training run (the "training horizon")

    def velocities(self, v: np.ndarray) -> np.ndarray:
        return (v - np.asarray(self.velocity_mean)) / np.asarray(self.velocity_std)

    def acceleration(self, a: np.ndarray) -> np.ndarray:
        return (a - np.asarray(self.acceleration_mean)) / np.asarray(self.acceleration_std)

    def acceleration_back(self, u: np.ndarray) -> np.ndarray:
        return np.asarray(u) * np.asarray(self.acceleration_std) + np.asarray(self.acceleration_mean)

    def scalars(self, values: dict[str, float]) -> np.ndarray:
        out = [scaled_scalar(values, name, self.scalar_lo, self.scalar_hi) for name in self.conditioning]
        return np.asarray(out, dtype=np.float32)

    @classmethod
    def fit(cls, runs: list[tuple[Path, dict[str, float]]], kind: str, scene: dict[str, Any], history: int,
            conditioning: list[str]) -> GnsNormalizer:
        """Statistics of the velocities and accelerations of every particle step of the training runs."""

        def trajectories() -> Iterator[tuple[np.ndarray, float, float]]:
            for path, _ in runs:
                with ParticleRun(path, kind, scene) as run:  # validates every training file once
                    yield run.positions(), run.dt, float(np.mean(run.diameters))

        return cls.from_trajectories(trajectories(), [values for _, values in runs], kind, history, conditioning)

    @classmethod
    def from_trajectories(cls, trajectories: Iterable[tuple[np.ndarray, float, float]],
                          values_of_runs: list[dict[str, float]], kind: str, history: int,
                          conditioning: list[str]) -> GnsNormalizer:
        """`fit` from (positions (T, N, 3) [m] with NaN = absent, dt [s], mean diameter [m]) per training run and
        each run's conditioning scalars."""
        sums = {"v": [np.zeros(3), np.zeros(3), 0], "a": [np.zeros(3), np.zeros(3), 0]}
        lengths, dts, horizon = [], [], 0
        for x, dt, diameter in trajectories:
            lengths.append(diameter)
            dts.append(dt)
            horizon = max(horizon, len(x) - 1)
            v = (x[1:] - x[:-1]) / dt
            a = (x[2:] - 2 * x[1:-1] + x[:-2]) / dt**2
            for key, arr in (("v", v), ("a", a)):
                ok = arr[np.isfinite(arr).all(axis=-1)]
                sums[key][0] += ok.sum(axis=0)
                sums[key][1] += (ok**2).sum(axis=0)
                sums[key][2] += len(ok)
        if max(dts) - min(dts) > 1e-9 * max(dts):
            raise DataError(f"training runs have different snapshot intervals {sorted(set(dts))}: one GNS steps "
                            "with one dt")
        stats = {}
        for key, (s, s2, n) in sums.items():
            if n == 0:
                raise DataError(f"the training runs have no particle with {history + 2} consecutive snapshots")
            mean = s / n
            std = np.sqrt(np.maximum(s2 / n - mean**2, 0.0))
            stats[key] = (mean.tolist(), np.maximum(std, STD_FLOOR * std.max() + 1e-12).tolist())
        values = {name: [vals[name] for vals in values_of_runs if name in vals] for name in conditioning}
        for name, vals in values.items():
            if len(vals) < len(values_of_runs):
                raise DataError(f"conditioning scalar {name!r} is missing for some training runs; run datagen "
                                "with data.characterization.enabled=true")
        return cls(kind=kind, length=float(np.mean(lengths)), dt=float(dts[0]), history=history,
                   conditioning=list(conditioning), velocity_mean=stats["v"][0], velocity_std=stats["v"][1],
                   acceleration_mean=stats["a"][0], acceleration_std=stats["a"][1],
                   scalar_lo={k: float(min(v)) for k, v in values.items()},
                   scalar_hi={k: float(max(v)) for k, v in values.items()}, horizon_steps=horizon)


def graph_inputs(norm: GnsNormalizer, run: ParticleRun, history_positions: np.ndarray,
                 scalars: np.ndarray) -> dict[str, torch.Tensor]:
    """The net's inputs for one run from its last H + 1 positions (H + 1, N, 3) [m] (the last is now), as
    float32 tensors (pos and box in particle diameters; one graph: box (1, 3), scalars (1, S))."""
    x = np.asarray(history_positions, dtype=np.float64)
    v = np.moveaxis((x[1:] - x[:-1]) / norm.dt, 0, 1)  # (N, H, 3)

    def t(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))

    return {"pos": t(x[-1] / norm.length), "velocities": t(norm.velocities(v)),
            "box_lo": t(run.box_lo[None] / norm.length), "box_hi": t(run.box_hi[None] / norm.length),
            "wall_distance": t(extra_wall_distances(run, x[-1]) / norm.length), "scalars": t(scalars[None])}


class GnsSamples(FileSamples):
    """Every (run, snapshot t) with H earlier snapshots and a next one (every `time_stride`-th t)."""

    def __init__(self, dataset_dir: Path, records: list[SimRecord], kind: str, scene: dict[str, Any],
                 norm: GnsNormalizer, noise_std: float, random: bool, seed: int = 0, time_stride: int = 1):
        self.dir = Path(dataset_dir)
        self.records, self.kind, self.scene, self.norm = records, kind, scene, norm
        self.noise_std = noise_std
        h = norm.history
        self.items: list[tuple[int, int]] = []
        for s, rec in enumerate(records):
            with ParticleRun(self.dir / str(rec.file), kind, scene, validate=False) as run:
                n = run.n_snapshots
            self.items += [(s, t) for t in range(h, n - 1, time_stride)]
        super().__init__(random, seed)

    def __len__(self) -> int:
        return len(self.items)

    def _open_file(self, s: int) -> ParticleRun:
        return ParticleRun(self.dir / str(self.records[s].file), self.kind, self.scene, validate=False)

    def conditioning(self, s: int) -> dict[str, float]:
        """The conditioning scalars of run `s`."""
        return self.records[s].conditioning()

    def sample(self, i: int, rng: np.random.Generator) -> Data:
        s, t = self.items[i]
        run, norm = self._open(s), self.norm
        h, dt = norm.history, norm.dt
        window = run.positions(slice(t - h, t + 2))  # (H + 2, N, 3): t - H .. t + 1
        nodes = np.flatnonzero(np.isfinite(window[h]).all(axis=1))
        hist, nxt = window[: h + 1, nodes], window[h + 1, nodes]
        mask = np.isfinite(nxt).all(axis=1)
        accel = np.zeros((len(nodes), 3))
        accel[mask] = (nxt[mask] - 2 * hist[-1, mask] + hist[-2, mask]) / dt**2
        if self.noise_std > 0:
            noise = random_walk_noise(rng, len(nodes), h, self.noise_std) * np.asarray(norm.velocity_std)
            v = np.moveaxis((hist[1:] - hist[:-1]) / dt, 0, 1) + noise  # (n, H, 3) noisy velocities
            hist = hist[0][None] + dt * np.concatenate([np.zeros((1, len(nodes), 3)),
                                                        np.cumsum(np.moveaxis(v, 1, 0), axis=0)])
            accel = accel - noise[:, -1] / dt  # one step from the noisy state reaches the true next velocity
        scalars = norm.scalars(self.conditioning(s))
        x = graph_inputs(norm, run, hist, scalars)
        target = torch.from_numpy(norm.acceleration(accel).astype(np.float32))
        return Data(num_nodes=len(nodes), y=target, mask=torch.from_numpy(mask), **x)


class GnsLoaders(PartLoaders):
    """What every GNS datamodule shares (from a dataset here, from an export in `neuraldem.export`): graph
    batches and the sample options, each checked with its config key."""

    loader_class = GraphLoader

    def __init__(self, conditioning: list[str] | None = None, history: int = 5, noise_std: float = 0.0,
                 batch_size: int = 2, num_workers: int = 0, seed: int = 0, eval_time_stride: int = 1):
        super().__init__()
        self._conditioning = None if conditioning is None else checks.names(
            "data.conditioning", list(conditioning), allowed=sorted({n for v in CONDITIONING.values() for n in v}))
        self.history = checks.positive_int("data.datamodule.history", history)
        if self.history > MAX_HISTORY:
            raise ConfigError(f"config value data.datamodule.history={history} is invalid: must be <= "
                              f"{MAX_HISTORY} (the GNS paper uses 5) (override it, e.g. data.datamodule.history=5)")
        self.noise_std = checks.number("data.datamodule.noise_std", noise_std, lo=0.0, hi=MAX_NOISE)
        self.batch_size = checks.positive_int("data.datamodule.batch_size", batch_size)
        self.num_workers = checks.positive_int("data.datamodule.num_workers", num_workers, allow_zero=True)
        self.seed = checks.positive_int("data.datamodule.seed", seed, allow_zero=True)
        self.eval_time_stride = checks.positive_int("data.datamodule.eval_time_stride", eval_time_stride)
        self.norm: GnsNormalizer | None = None


class GnsDataModule(GnsLoaders):
    """Train/val/test loaders (torch_geometric batches: one graph per sample) over a hopper or
    fluidized-bed dataset, for one conditioning list and one split of the manifest."""

    def __init__(self, dataset_dir: str, name: str, conditioning: list[str] | None = None, split: str | None = None,
                 history: int = 5, noise_std: float = 0.0, batch_size: int = 2, num_workers: int = 0, seed: int = 0,
                 eval_time_stride: int = 1):
        super().__init__(conditioning, history, noise_std, batch_size, num_workers, seed, eval_time_stride)
        self.dataset_dir = Path(dataset_dir)
        self.name = name
        self._split = split
        self.manifest: Manifest | None = None
        self.datasets: dict[str, GnsSamples] = {}

    # ---- facts about the data
    @property
    def kind(self) -> str:
        assert self.manifest is not None
        return self.manifest.kind

    @property
    def conditioning(self) -> list[str]:
        return list(self._conditioning) if self._conditioning is not None else list(CONDITIONING[self.kind][:3])

    @property
    def split(self) -> str:
        return self._split or SPLITS[self.kind][0]

    def records(self, part: str) -> list[SimRecord]:
        assert self.manifest is not None
        return [self.manifest.record(i) for i in self.manifest.split_ids(self.split, part)]

    def prepare_manifest(self) -> Manifest:
        if self.manifest is None:
            m = require_dataset(self.dataset_dir, self.name)
            if m.kind not in SCENES:
                raise DataError(f"dataset {self.dataset_dir} holds {m.kind!r} data; the GNS baseline reads "
                                f"{list(SCENES)} datasets")
            self.manifest = m
            checks.names("data.conditioning", self.conditioning, allowed=CONDITIONING[m.kind])
            checks.one_of("data.split", self.split, SPLITS[m.kind])
            if not m.splits.get(self.split, {}).get("train"):
                raise DataError(f"dataset {self.dataset_dir}: split {self.split!r} has no training runs; generate "
                                f"more with neuraldem datagen data={self.name} n_sims=N")
        return self.manifest

    def setup(self, stage: str | None = None) -> None:
        if self.datasets:
            return
        m = self.prepare_manifest()
        paths = {part: [self.dataset_dir / str(r.file) for r in self.records(part)]
                 for part in ("train", "val", "test")}
        if self.norm is None:
            runs = [(p, r.conditioning()) for p, r in zip(paths["train"], self.records("train"), strict=False)]
            self.norm = GnsNormalizer.fit(runs, m.kind, m.scene, self.history, self.conditioning)
        for part in ("val", "test"):
            for path in paths[part]:
                ParticleRun(path, m.kind, m.scene).close()  # validate once, up front
        if not self.records("val"):
            log.warning("dataset %s: split %r has no validation runs; training runs without validation",
                        self.dataset_dir, self.split)
        for part in ("train", "val", "test"):
            train = part == "train"
            self.datasets[part] = GnsSamples(self.dataset_dir, self.records(part), m.kind, m.scene, self.norm,
                                             self.noise_std if train else 0.0, random=train, seed=self.seed,
                                             time_stride=1 if train else self.eval_time_stride)
        if not len(self.datasets["train"]):
            raise ConfigError(f"config value data.datamodule.history={self.history} is invalid: no training run of "
                              f"{self.dataset_dir} has {self.history + 2} snapshots (override it, e.g. "
                              "data.datamodule.history=2)")

    def checkpoint_metadata(self) -> dict[str, Any]:
        """What a rollout needs to use a trained GNS correctly (in every checkpoint). `kind` is "gns" so that
        the field surrogates' tools refuse it; `scene_kind` says which data it was trained on."""
        assert self.manifest is not None and self.norm is not None
        meta = {"kind": "gns", "scene_kind": self.kind, "data_name": self.name, "scene": self.manifest.scene,
                "conditioning": self.conditioning, "split": self.split, "normalizer": self.norm.to_dict(),
                "history": self.history, "n_extra_walls": N_EXTRA_WALLS[self.kind], "noise_std": self.noise_std}
        if self.kind == "fluidized_bed":
            meta["train_velocities"] = sorted({float(r.params["inlet_velocity"]) for r in self.records("train")})
        return meta
