"""RefillDataModule: (simulation, time t, reference time t_ref) samples from a refilling-hopper dataset.

The targets are relative to t_ref (neuraldem.scenes.hopper_refill.targets): transport = position at t_ref of the
material now at a point (material inserted after t_ref is left out of the transport loss:
`transport_mask`), residence = time spent in the hopper since t_ref. The model is conditioned on
dt_ref = t - t_ref (scaled by the window), optionally on t_ref itself, and on the simulation's scalars.
With `random_reference` the training draws t_ref afresh for every sample, uniformly among the snapshots in
[t - window, t]; validation and test draw it once from (seed, index), so every epoch sees the same pairs.
Without it t_ref is always t - window (or the opening, 0, early in the run).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from neuraldem.config import checks
from neuraldem.data.file_samples import FileSamples
from neuraldem.data.manifest import SimRecord
from neuraldem.data.normalization import HopperNormalizer
from neuraldem.errors import ConfigError
from neuraldem.scenes.hopper.surrogate.datamodule import HopperDataModule, occupancy_samples, query_tensors
from neuraldem.scenes.hopper_refill.store import RefillFile
from neuraldem.scenes.hopper_refill.targets import particle_targets

REFILL_CONDITIONING = ("dt_ref", "t_ref", "alpha", "mu_s", "mu_r", "theta", "repose")


def reference_scalars(record: SimRecord, t: float, t_ref: float) -> dict[str, float]:
    """Every scalar a refill model may be conditioned on, for one (simulation, t, t_ref)."""
    return {**record.conditioning(), "dt_ref": t - t_ref, "t_ref": t_ref}


class RefillSamples(FileSamples):
    """All (simulation, snapshot t) pairs; t_ref is drawn per sample in [t - window, t]."""

    def __init__(self, dataset_dir: Path, records: list[SimRecord], conditioning: list[str],
                 norm: HopperNormalizer, snapshot_interval: float, window: float, n_queries: int,
                 negative_fraction: float, occupancy_radius: float, random_queries: bool, seed: int = 0,
                 time_stride: int = 1, n_snapshots: list[int] | None = None, random_reference: bool = True):
        self.dir = Path(dataset_dir)
        self.records = records
        self.conditioning = conditioning
        self.norm = norm
        self.dt = snapshot_interval
        self.window_steps = round(window / snapshot_interval)
        self.random_reference = random_reference
        self.n_queries = n_queries
        self.n_negative = round(negative_fraction * n_queries)
        self.radius = occupancy_radius
        counts = n_snapshots or [0] * len(records)
        self.items = [(s, k) for s in range(len(records)) for k in range(0, counts[s], time_stride)]
        super().__init__(random_queries, seed)

    def __len__(self) -> int:
        return len(self.items)

    def _open_file(self, s: int) -> RefillFile:
        return RefillFile(self.dir / str(self.records[s].file), validate=False)  # validated in setup()

    def reference_index(self, i: int, rng: np.random.Generator) -> int:
        """Uniform among the snapshots in [t - window, t] (random_reference), else always t - window (or 0)."""
        _, k = self.items[i]
        first = max(0, k - self.window_steps)
        return int(rng.integers(first, k + 1)) if self.random_reference else first

    def sample(self, i: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
        s, k = self.items[i]
        f = self._open(s)
        k_ref = self.reference_index(i, rng)
        t, t_ref = float(f.times[k]), float(f.times[k_ref])
        rows, pos = f.frame(k)
        rows_ref, pos_ref = f.frame(k_ref)
        q = self.n_queries
        lo, hi = np.asarray(self.norm.box_lo), np.asarray(self.norm.box_hi)
        occ_pos, occ = occupancy_samples(rng, pos, q, self.n_negative, self.radius, lo, hi)
        if len(rows):
            pick = rng.choice(len(rows), q, replace=len(rows) < q)
            tg = particle_targets(t, t_ref, rows[pick], pos[pick], rows_ref, pos_ref, f.insert_times)
            part_pos, mask = pos[pick], np.ones(q, dtype=bool)
            transport_mask = ~tg.new
            transport = self.norm.positions(np.where(transport_mask[:, None], tg.transport, 0.5 * (lo + hi)))
            residence = self.norm.time(tg.residence)
        else:
            part_pos, mask = np.full((q, 3), 0.5 * (lo + hi)), np.zeros(q, dtype=bool)
            transport_mask = mask
            transport, residence = np.zeros((q, 3)), np.zeros(q)
        scalars = self.norm.scalars(reference_scalars(self.records[s], t, t_ref), self.conditioning, t)
        return {
            **query_tensors(self.norm, scalars, occ_pos, occ, part_pos, mask),
            "transport_mask": torch.from_numpy(transport_mask & mask),
            "transport": torch.from_numpy(transport).float(),
            "residence": torch.from_numpy(np.asarray(residence)).float(),
        }


class RefillDataModule(HopperDataModule):
    """Loaders over a refilling-hopper dataset; the first conditioning scalar is dt_ref = t - t_ref."""

    KIND = "hopper_refill"
    CONDITIONING = REFILL_CONDITIONING
    FIRST_SCALAR = "dt_ref"

    def __init__(self, dataset_dir: str, name: str, conditioning: list[str], window: float,
                 random_reference: bool = True, negative_fraction: float = 0.5, **kwargs: Any):
        super().__init__(dataset_dir, name, conditioning, **kwargs)
        self.negative_fraction = checks.fraction("data.datamodule.negative_fraction", negative_fraction)
        self.window = checks.positive("data.reference.window", window)
        if not isinstance(random_reference, bool):
            raise ConfigError(f"config value data.datamodule.random_reference={random_reference!r} is invalid: "
                              "must be true or false (override it, e.g. data.datamodule.random_reference=true)")
        self.random_reference = random_reference

    @property
    def refill(self) -> dict[str, Any]:
        return dict(self.scene.get("refill", {}))

    def fit_normalizer(self) -> HopperNormalizer:
        """Scene box from the geometry (up to the top of the wall, where material is inserted); times scaled
        by the window; scalar ranges from the training simulations."""
        train = self.records("train")
        d = self.particle_diameter
        dt = self.snapshot_interval
        steps = round(self.window / dt)
        if steps < 1 or abs(steps * dt - self.window) > 1e-6:
            raise ConfigError(f"config value data.reference.window={self.window} is invalid: must be a positive "
                              f"multiple of the snapshot interval {dt} s")
        lo, hi, duration = np.full(3, np.inf), np.full(3, -np.inf), 0.0
        for rec in train:
            with RefillFile(self.dataset_dir / str(rec.file)) as f:  # validates every training file once
                box_lo, box_hi = f.geometry.box()
                lo, hi = np.minimum(lo, box_lo), np.maximum(hi, box_hi)
                duration = max(duration, float(f.times[-1]))
        if self.window > duration:
            raise ConfigError(f"config value data.reference.window={self.window} is invalid: longer than the "
                              f"simulations ({duration:g} s); lower it")
        values = {name: [r.conditioning()[name] for r in train if name in r.conditioning()]
                  for name in self.conditioning if name not in ("dt_ref", "t_ref")}
        scalar_lo = {k: float(min(v)) for k, v in values.items() if v}
        scalar_hi = {k: float(max(v)) for k, v in values.items() if v}
        scalar_lo.update(dt_ref=0.0, t_ref=0.0)
        scalar_hi.update(dt_ref=self.window, t_ref=duration)
        return HopperNormalizer(box_lo=(lo - d).tolist(), box_hi=(hi + d).tolist(), horizon=self.window,
                                scalar_lo=scalar_lo, scalar_hi=scalar_hi)

    def build_datasets(self) -> None:
        """One RefillSamples per part, with each file's snapshot count (the val and test files validated)."""
        assert self.norm is not None
        for part in ("train", "val", "test"):
            counts = []
            for rec in self.records(part):
                with RefillFile(self.dataset_dir / str(rec.file), validate=part != "train") as f:
                    counts.append(f.n_snapshots)
            self.datasets[part] = RefillSamples(
                self.dataset_dir, self.records(part), self.conditioning, self.norm, self.snapshot_interval,
                self.window, self.n_queries, self.negative_fraction, self.occupancy_radius_d * self.particle_diameter,
                random_queries=part == "train", seed=self.seed,
                time_stride=1 if part == "train" else self.eval_time_stride, n_snapshots=counts,
                random_reference=self.random_reference)

    def checkpoint_metadata(self) -> dict[str, Any]:
        meta = super().checkpoint_metadata()
        meta.update(kind="hopper_refill", reference={"window": self.window})
        return meta
