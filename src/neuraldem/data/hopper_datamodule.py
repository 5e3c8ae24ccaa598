"""HopperDataModule: (simulation, time) samples with random query points, streamed from the HDF5 files.

Targets per the paper (sec. 4.2), at query points in normalised coordinates:
- occupancy: label of points near particles (centres jittered within the occupancy radius) and of points
  drawn uniformly in the scene box (negatives, and whatever they hit);
- transport: for particles present at t, their initial position;
- residence: for particles present at t, the time until they exit (the horizon if they never do).
Every simulation is extended to the horizon by holding its final state (a drained or stalled hopper does
not change), so the model is asked about one fixed time range.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from scipy.spatial import cKDTree
from torch.utils.data import DataLoader

from neuraldem.config import checks
from neuraldem.data.file_samples import FileSamples
from neuraldem.data.hopper_fields import capped_exit_times
from neuraldem.data.hopper_store import HopperFile
from neuraldem.data.manifest import Manifest, SimRecord, require_dataset
from neuraldem.data.normalization import HopperNormalizer
from neuraldem.errors import ConfigError, DataError

CONDITIONING_NAMES = ("t", "alpha", "mu_s", "mu_r", "theta", "repose")
SPLITS = ("random", "band")


class HopperSnapshots(FileSamples):
    """All (simulation, snapshot) pairs of some simulations, on the horizon's time grid."""

    def __init__(self, dataset_dir: Path, records: list[SimRecord], conditioning: list[str],
                 norm: HopperNormalizer, snapshot_interval: float, n_queries: int, negative_fraction: float,
                 occupancy_radius: float, random_queries: bool, seed: int = 0, time_stride: int = 1):
        self.dir = Path(dataset_dir)
        self.records = records
        self.conditioning = conditioning
        self.norm = norm
        self.dt = snapshot_interval
        self.n_queries = n_queries
        self.n_negative = int(round(negative_fraction * n_queries))
        self.radius = occupancy_radius
        n_grid = int(round(norm.horizon / snapshot_interval)) + 1
        self.items = [(s, k) for s in range(len(records)) for k in range(0, n_grid, time_stride)]
        super().__init__(random_queries, seed)

    def __len__(self) -> int:
        return len(self.items)

    def _open_file(self, s: int) -> tuple[HopperFile, np.ndarray, np.ndarray]:
        f = HopperFile(self.dir / str(self.records[s].file), validate=False)  # validated in setup()
        return f, f.initial_positions(), capped_exit_times(f.exit_times, self.norm.horizon)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        s, k = self.items[i]
        f, initial, exits = self._open(s)
        t = k * self.dt
        pos = f.positions(min(k, f.n_snapshots - 1))
        present = np.flatnonzero(np.isfinite(pos[:, 0]))
        rng = self._rng(i)
        q = self.n_queries

        lo, hi = np.asarray(self.norm.box_lo), np.asarray(self.norm.box_hi)
        occ_pos, occ = occupancy_samples(rng, pos[present], q, self.n_negative, self.radius, lo, hi)

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
            "scalars": torch.from_numpy(scalars),
            "occupancy_pos": torch.from_numpy(self.norm.positions(occ_pos)).float(),
            "occupancy": torch.from_numpy(occ),
            "particle_pos": torch.from_numpy(self.norm.positions(part_pos)).float(),
            "particle_mask": torch.from_numpy(mask),
            "transport": torch.from_numpy(transport).float(),
            "residence": torch.from_numpy(np.asarray(residence)).float(),
        }


def occupancy_samples(rng: np.random.Generator, centres: np.ndarray, n_queries: int, n_negative: int,
                      radius: float, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Occupancy queries and labels: particle `centres` (n, 3) jittered within `radius`, plus `n_negative`
    points drawn uniformly in the box [lo, hi], labelled by whether a centre lies within `radius`."""
    n_near = n_queries - n_negative if len(centres) else 0
    near = centres[rng.choice(len(centres), n_near)] + _in_ball(rng, n_near, radius) if n_near else np.zeros((0, 3))
    uniform = lo + rng.random((n_queries - n_near, 3)) * (hi - lo)
    occ_pos = np.clip(np.concatenate([near, uniform]), lo, hi)
    occ = np.zeros(n_queries, dtype=np.float32)
    if len(centres):
        dist, _ = cKDTree(centres).query(occ_pos, k=1, distance_upper_bound=radius)
        occ = np.isfinite(dist).astype(np.float32)
    return occ_pos, occ


def _in_ball(rng: np.random.Generator, n: int, radius: float) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v * radius * rng.random((n, 1)) ** (1 / 3)


class HopperDataModule(L.LightningDataModule):
    """Train/val/test loaders over a hopper dataset dir, for one conditioning list and one split."""

    KIND = "hopper"  # the dataset kind it reads
    CONDITIONING = CONDITIONING_NAMES  # scalars a model may be conditioned on
    FIRST_SCALAR = "t"  # the time scalar, always first

    def __init__(self, dataset_dir: str, name: str, conditioning: list[str], split: str = "random",
                 batch_size: int = 8, n_queries: int = 1024, negative_fraction: float = 0.5,
                 occupancy_radius_d: float = 0.6, num_workers: int = 0, seed: int = 0,
                 eval_time_stride: int = 4):
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
        self.negative_fraction = checks.fraction("data.datamodule.negative_fraction", negative_fraction)
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
        return [self.manifest.record(i) for i in self.manifest.split_ids(self.split, part)]

    def prepare_manifest(self) -> Manifest:
        if self.manifest is None:
            m = require_dataset(self.dataset_dir, self.name)
            if m.kind != self.KIND:
                raise DataError(f"dataset {self.dataset_dir} holds {m.kind!r} data, not {self.KIND} data")
            for part in ("train", "val", "test"):
                if not m.splits.get(self.split, {}).get(part):
                    raise DataError(f"dataset {self.dataset_dir}: split {self.split!r} has no {part} "
                                    "simulations; generate more with python -m neuraldem.datagen "
                                    f"data={self.name} n_sims=N")
            self.manifest = m
        return self.manifest

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
        if self.datasets:
            return
        self.prepare_manifest()
        if self.norm is None:
            self.norm = self.fit_normalizer()
        for part in ("val", "test"):
            for rec in self.records(part):
                HopperFile(self.dataset_dir / str(rec.file)).close()  # validate once, up front
        for part in ("train", "val", "test"):
            self.datasets[part] = HopperSnapshots(
                self.dataset_dir, self.records(part), self.conditioning, self.norm, self.snapshot_interval,
                self.n_queries, self.negative_fraction, self.occupancy_radius_d * self.particle_diameter,
                random_queries=part == "train", seed=self.seed,
                time_stride=1 if part == "train" else self.eval_time_stride)

    def _loader(self, part: str, shuffle: bool) -> DataLoader:
        return DataLoader(self.datasets[part], batch_size=self.batch_size, shuffle=shuffle,
                          num_workers=self.num_workers, persistent_workers=self.num_workers > 0,
                          drop_last=shuffle)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)

    def checkpoint_metadata(self) -> dict[str, Any]:
        """What evaluation needs to use a trained model correctly (stored in every checkpoint)."""
        assert self.manifest is not None and self.norm is not None
        return {"kind": "hopper", "data_name": self.name, "scene": self.scene, "conditioning": self.conditioning,
                "split": self.split, "normalizer": self.norm.to_dict(),
                "occupancy_radius_d": self.occupancy_radius_d}
