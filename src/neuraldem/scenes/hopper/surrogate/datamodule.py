"""HopperDataModule: (simulation, time) samples with random query points, streamed from the HDF5 files.

Targets per the paper (sec. 4.2), at query points in normalised coordinates:
- occupancy: is a particle centre within the occupancy radius of the point. The points are drawn without
  looking at the labels (`occupancy_queries`): the run's initial particle positions jittered by up to
  `jitter_d` diameters, plus a `box_fraction` drawn uniformly in the scene box. The BCE optimum is then the
  occupancy probability at each point, so soft counts at the initial positions (the metrics' query points)
  are unbiased; drawing positives around the current particles made the model over-predict occupancy;
- transport: for particles present at t, their initial position;
- residence: for particles present at t, the time until they exit (the horizon if they never do).
Every simulation is extended to the horizon (the scene's `max_time`) by holding its final state (a drained
or stalled hopper does not change), so the model is asked about one fixed time range. Training draws a
`tail_share` of its samples from that held tail and the rest from the active run, where the answers change.
With `fold` set, train/val/test come from a cross-validation fold (`data.splits.cv_split`) instead of the
manifest's split; the ids used travel in the checkpoint either way.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy.spatial import cKDTree

from neuraldem.config import checks
from neuraldem.data.file_samples import FileSamples
from neuraldem.data.manifest import Manifest, SimRecord, require_dataset
from neuraldem.data.normalization import HopperNormalizer
from neuraldem.data.part_loaders import PartLoaders
from neuraldem.data.splits import cv_split
from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes.hopper.dataset.fields import capped_exit_times
from neuraldem.scenes.hopper.dataset.store import HopperFile

CONDITIONING_NAMES = ("t", "alpha", "mu_s", "mu_r", "theta", "repose")
SPLITS = ("random", "band")


class HopperSnapshots(FileSamples):
    """All (simulation, snapshot) pairs of some simulations, on the horizon's time grid."""

    def __init__(self, dataset_dir: Path, records: list[SimRecord], conditioning: list[str],
                 norm: HopperNormalizer, snapshot_interval: float, n_queries: int, box_fraction: float,
                 jitter: float, occupancy_radius: float, random_queries: bool, seed: int = 0,
                 time_stride: int = 1):
        self.dir = Path(dataset_dir)
        self.records = records
        self.conditioning = conditioning
        self.norm = norm
        self.dt = snapshot_interval
        self.n_queries = n_queries
        self.n_box = int(round(box_fraction * n_queries))
        self.jitter = jitter
        self.radius = occupancy_radius
        n_grid = int(round(norm.horizon / snapshot_interval)) + 1
        self.items = [(s, k) for s in range(len(records)) for k in range(0, n_grid, time_stride)]
        super().__init__(random_queries, seed)

    def __len__(self) -> int:
        return len(self.items)

    def _open_file(self, s: int) -> tuple[HopperFile, np.ndarray, np.ndarray]:
        f = HopperFile(self.dir / str(self.records[s].file), validate=False)  # validated in setup()
        return f, f.initial_positions(), capped_exit_times(f.exit_times, self.norm.horizon)

    def active_mask(self) -> np.ndarray:
        """(len,) True for samples inside their run (before the solver stopped it), False in the held tail."""
        n_stored = []
        for s in range(len(self.records)):
            n_stored.append(self._open(s)[0].n_snapshots)
        return np.array([k < n_stored[s] for s, k in self.items])

    def sample(self, i: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
        s, k = self.items[i]
        f, initial, exits = self._open(s)
        t = k * self.dt
        pos = f.positions(min(k, f.n_snapshots - 1))
        present = np.flatnonzero(np.isfinite(pos[:, 0]))
        q = self.n_queries

        lo, hi = np.asarray(self.norm.box_lo), np.asarray(self.norm.box_hi)
        occ_pos = occupancy_queries(rng, initial, q, self.n_box, self.jitter, lo, hi)
        occ = occupancy_labels(occ_pos, pos[present], self.radius)

        # transport / residence at the particles present now
        if len(present):
            pick = rng.choice(present, q, replace=len(present) < q)
            part_pos, mask = pos[pick], np.ones(q, dtype=bool)
            transport = self.norm.positions(initial[pick])
            residence = self.norm.time(exits[pick] - t)
        else:  # an empty hopper: nothing to supervise but the occupancy
            part_pos, mask = np.full((q, 3), 0.5 * (lo + hi)), np.zeros(q, dtype=bool)
            transport, residence = np.zeros((q, 3)), np.zeros(q)
        scalars = self.norm.scalars(self.records[s].conditioning(), self.conditioning, t)
        return {
            **query_tensors(self.norm, scalars, occ_pos, occ, part_pos, mask),
            "transport": torch.from_numpy(transport).float(),
            "residence": torch.from_numpy(np.asarray(residence)).float(),
        }


def query_tensors(norm: HopperNormalizer, scalars: np.ndarray, occ_pos: np.ndarray, occ: np.ndarray,
                  part_pos: np.ndarray, mask: np.ndarray) -> dict[str, torch.Tensor]:
    """The model inputs and occupancy labels of one sample (positions normalised into the scene box): the same
    keys and dtypes for the draining and the refilling hopper, whose targets follow them."""
    return {
        "scalars": torch.from_numpy(scalars),
        "occupancy_pos": torch.from_numpy(norm.positions(occ_pos)).float(),
        "occupancy": torch.from_numpy(occ),
        "particle_pos": torch.from_numpy(norm.positions(part_pos)).float(),
        "particle_mask": torch.from_numpy(mask),
    }


def occupancy_queries(rng: np.random.Generator, initial: np.ndarray, n_queries: int, n_box: int, jitter: float,
                      lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Occupancy query points that do not depend on the labels: `n_box` uniform in the box [lo, hi], the
    rest at initial particle positions (the points the metrics are evaluated at) jittered within `jitter`."""
    n_near = n_queries - n_box if len(initial) else 0
    near = initial[rng.choice(len(initial), n_near)] + _in_ball(rng, n_near, jitter) if n_near else np.zeros((0, 3))
    uniform = lo + rng.random((n_queries - n_near, 3)) * (hi - lo)
    return np.clip(np.concatenate([near, uniform]), lo, hi)


def occupancy_labels(points: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
    """1 where a particle centre lies within `radius` of the point, else 0 (float32)."""
    if not len(centres):
        return np.zeros(len(points), dtype=np.float32)
    dist, _ = cKDTree(centres).query(points, k=1, distance_upper_bound=radius)
    return np.isfinite(dist).astype(np.float32)


def occupancy_samples(rng: np.random.Generator, centres: np.ndarray, n_queries: int, n_negative: int,
                      radius: float, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The refilling hopper's occupancy queries (label-dependent): particle `centres` jittered within
    `radius`, plus `n_negative` points uniform in the box [lo, hi]. The draining hopper uses the unbiased
    `occupancy_queries`; a refill model's occupancy is not scored by soft counts."""
    n_near = n_queries - n_negative if len(centres) else 0
    near = centres[rng.choice(len(centres), n_near)] + _in_ball(rng, n_near, radius) if n_near else np.zeros((0, 3))
    uniform = lo + rng.random((n_queries - n_near, 3)) * (hi - lo)
    occ_pos = np.clip(np.concatenate([near, uniform]), lo, hi)
    return occ_pos, occupancy_labels(occ_pos, centres, radius)


def _in_ball(rng: np.random.Generator, n: int, radius: float) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v * radius * rng.random((n, 1)) ** (1 / 3)


def cv_records(m: Manifest, n_sims: int | None, dataset_dir: Path) -> list[SimRecord]:
    """The usable runs among the first `n_sims` simulations of the parameter table (all usable runs for None);
    refused while one of those is still pending, so every fold sees one fixed set of runs."""
    if n_sims is None:
        return m.usable()
    if n_sims > len(m.simulations):
        raise DataError(f"data.datamodule.n_sims={n_sims} but {dataset_dir} has {len(m.simulations)} simulations: "
                        f"lower it or generate more with neuraldem datagen data={m.name} n_sims={n_sims}")
    pending = [r.sim_id for r in m.simulations[:n_sims] if r.status == "pending"]
    if pending:
        raise DataError(f"{len(pending)} of the first {n_sims} simulations of {dataset_dir} are not finished (e.g. "
                        f"{pending[0]}): wait for datagen, or lower data.datamodule.n_sims")
    return [r for r in m.simulations[:n_sims] if r.usable]


def tail_weights(active: np.ndarray, tail_share: float) -> np.ndarray:
    """Sampling weights that draw `tail_share` of the samples from the held tail, the rest from active runs."""
    n_active, n_tail = int(active.sum()), int((~active).sum())
    if n_tail == 0 or n_active == 0:
        return np.ones(len(active))
    return np.where(active, (1 - tail_share) / n_active, tail_share / n_tail)


class HopperDataModule(PartLoaders):
    """Train/val/test loaders over a hopper dataset dir, for one conditioning list and one split."""

    KIND = "hopper"  # the dataset kind it reads
    CONDITIONING = CONDITIONING_NAMES  # scalars a model may be conditioned on
    FIRST_SCALAR = "t"  # the time scalar, always first

    def __init__(self, dataset_dir: str, name: str, conditioning: list[str], split: str = "random",
                 batch_size: int = 8, n_queries: int = 1024, box_fraction: float = 0.25, jitter_d: float = 0.5,
                 tail_share: float = 0.1, occupancy_radius_d: float = 0.8, num_workers: int = 0, seed: int = 0,
                 eval_time_stride: int = 4, fold: int | None = None, n_folds: int = 5, split_seed: int = 0,
                 val_fraction: float = 0.1, n_sims: int | None = None):
        super().__init__()
        self.dataset_dir = Path(dataset_dir)
        self.name = name
        self.conditioning = checks.names("data.conditioning", list(conditioning), allowed=self.CONDITIONING)
        if self.conditioning[0] != self.FIRST_SCALAR:
            raise ConfigError(f"config value data.conditioning={self.conditioning} is invalid: the first "
                              f"scalar must be the time {self.FIRST_SCALAR!r}")
        self.split = checks.one_of("data.split", split, SPLITS)
        self.batch_size = checks.positive_int("data.datamodule.batch_size", batch_size)
        self.n_queries = checks.positive_int("data.datamodule.n_queries", n_queries)
        self.box_fraction = checks.fraction("data.datamodule.box_fraction", box_fraction)
        self.jitter_d = checks.number("data.datamodule.jitter_d", jitter_d, lo=0.0, hi=2.0)
        self.tail_share = checks.fraction("data.datamodule.tail_share", tail_share)
        self.n_folds = checks.positive_int("data.datamodule.n_folds", n_folds)
        if self.n_folds < 2:
            raise ConfigError(f"config value data.datamodule.n_folds={n_folds} is invalid: cross-validation "
                              "needs >= 2 folds (override it, e.g. data.datamodule.n_folds=5)")
        self.fold = None if fold is None else checks.positive_int("data.datamodule.fold", fold, allow_zero=True)
        if self.fold is not None and self.fold >= self.n_folds:
            raise ConfigError(f"config value data.datamodule.fold={fold} is invalid: must be < n_folds="
                              f"{self.n_folds} (folds are 0 .. {self.n_folds - 1})")
        self.split_seed = checks.positive_int("data.datamodule.split_seed", split_seed, allow_zero=True)
        self.val_fraction = checks.fraction("data.datamodule.val_fraction", val_fraction)
        # cross-validation over the first n_sims simulations of the parameter table: folds that stay the same
        # while datagen adds runs (null = every usable run now)
        self.n_sims = None if n_sims is None else checks.positive_int("data.datamodule.n_sims", n_sims)
        self.split_ids: dict[str, list[str]] = {}
        self.occupancy_radius_d = checks.number("data.datamodule.occupancy_radius_d", occupancy_radius_d,
                                                lo=0.5, hi=2.0, lo_open=True)
        self.num_workers = checks.positive_int("data.datamodule.num_workers", num_workers, allow_zero=True)
        self.seed = checks.positive_int("data.datamodule.seed", seed, allow_zero=True)
        # validation/test visit every k-th snapshot: enough to track the loss, k times cheaper
        self.eval_time_stride = checks.positive_int("data.datamodule.eval_time_stride", eval_time_stride)
        self.manifest: Manifest | None = None
        self.norm: HopperNormalizer | None = None
        self.datasets: dict[str, HopperSnapshots] = {}

    # ---- facts about the data that the model and checkpoints need
    @property
    def scene(self) -> dict[str, Any]:
        assert self.manifest is not None
        return self.manifest.scene

    @property
    def particle_diameter(self) -> float:
        return float(self.scene["hopper"]["material"]["diameter"])

    @property
    def snapshot_interval(self) -> float:
        return float(self.scene["hopper"]["snapshot_interval"])

    def records(self, part: str) -> list[SimRecord]:
        assert self.manifest is not None
        return [self.manifest.record(i) for i in self.split_ids[part]]

    def prepare_manifest(self) -> Manifest:
        if self.manifest is None:
            m = require_dataset(self.dataset_dir, self.name)
            if m.kind != self.KIND:
                raise DataError(f"dataset {self.dataset_dir} holds {m.kind!r} data, not {self.KIND} data")
            self.split_ids = self.choose_split(m)
            for part in ("train", "val", "test"):
                if not self.split_ids.get(part):
                    raise DataError(f"dataset {self.dataset_dir}: split {self.split!r} has no {part} "
                                    "simulations; generate more with neuraldem datagen "
                                    f"data={self.name} n_sims=N")
            self.manifest = m
        return self.manifest

    def choose_split(self, m: Manifest) -> dict[str, list[str]]:
        """The manifest's split, or one fold of a cross-validation over its usable runs."""
        if self.fold is None:
            return {part: m.split_ids(self.split, part) for part in ("train", "val", "test")}
        records = cv_records(m, self.n_sims, self.dataset_dir)
        alpha = m.parameters.get("ranges", {}).get("alpha")
        if alpha is None:
            alphas = [r.params["alpha"] for r in records]
            alpha = [min(alphas), max(alphas)]
        return cv_split(records, self.split, self.fold, self.n_folds, self.split_seed, self.val_fraction,
                        (float(alpha[0]), float(alpha[1])), dataset=str(self.dataset_dir))

    def fit_normalizer(self) -> HopperNormalizer:
        """Scene box, horizon and scalar ranges from the training simulations only."""
        train = self.records("train")
        d = self.particle_diameter
        lo, hi, horizon = np.full(3, np.inf), np.full(3, -np.inf), 0.0
        for rec in train:
            with HopperFile(self.dataset_dir / str(rec.file)) as f:  # validates every training file once
                p0 = f.initial_positions()
                box_lo, box_hi = f.geometry.box()
                lo = np.minimum(lo, box_lo)
                hi = np.maximum(hi, [box_hi[0], box_hi[1], np.nanmax(p0[:, 2])])  # up to the fill, not the wall top
                horizon = max(horizon, float(f.times[-1]))
        horizon = max(horizon, float(self.scene["hopper"].get("max_time", 0.0)))  # the metrics' time range
        dt = self.snapshot_interval
        values = {name: [r.conditioning()[name] for r in train if name in r.conditioning()]
                  for name in self.conditioning if name != "t"}
        for name, vals in values.items():
            if len(vals) < len(train):
                raise DataError(f"conditioning scalar {name!r} is missing for some training simulations of "
                                f"{self.dataset_dir}; run datagen with data.characterization.enabled=true")
        return HopperNormalizer(box_lo=(lo - d).tolist(), box_hi=(hi + d).tolist(),
                                horizon=float(np.ceil(horizon / dt - 1e-9) * dt),
                                scalar_lo={k: float(min(v)) for k, v in values.items()},
                                scalar_hi={k: float(max(v)) for k, v in values.items()})

    def setup(self, stage: str | None = None) -> None:
        """Manifest, normaliser (fitted on the training runs unless given) and datasets, once per module."""
        if self.datasets:
            return
        self.prepare_manifest()
        if self.norm is None:
            self.norm = self.fit_normalizer()
        self.build_datasets()

    def build_datasets(self) -> None:
        """The train/val/test datasets; the val and test files are validated up front."""
        assert self.norm is not None
        for part in ("val", "test"):
            for rec in self.records(part):
                HopperFile(self.dataset_dir / str(rec.file)).close()  # validate once, up front
        for part in ("train", "val", "test"):
            self.datasets[part] = HopperSnapshots(
                self.dataset_dir, self.records(part), self.conditioning, self.norm, self.snapshot_interval,
                self.n_queries, self.box_fraction, self.jitter_d * self.particle_diameter,
                self.occupancy_radius_d * self.particle_diameter, random_queries=part == "train", seed=self.seed,
                time_stride=1 if part == "train" else self.eval_time_stride)

    def train_weights(self) -> np.ndarray | None:
        """Runs stop at different times; `tail_share` of the samples come from the held tail after the stop."""
        ds = self.datasets["train"]
        return tail_weights(ds.active_mask(), self.tail_share) if isinstance(ds, HopperSnapshots) else None

    def checkpoint_metadata(self) -> dict[str, Any]:
        """What evaluation needs to use a trained model correctly (stored in every checkpoint)."""
        assert self.manifest is not None and self.norm is not None
        return {"kind": "hopper", "data_name": self.name, "scene": self.scene, "conditioning": self.conditioning,
                "split": self.split, "fold": self.fold, "n_folds": self.n_folds if self.fold is not None else None,
                "split_ids": self.split_ids, "normalizer": self.norm.to_dict(),
                "occupancy_radius_d": self.occupancy_radius_d}
