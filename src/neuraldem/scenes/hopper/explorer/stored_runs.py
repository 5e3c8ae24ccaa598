"""Stored LIGGGHTS runs near the explored point: shown beside the model's answer when one is close enough.

The runs are the model's own training dataset (meta.json names it) or `dataset=DIR`, and only when its
scene is the model's. Near means every parameter within `near` (a share of its trained range) of the run's.
Without a dataset on disk the explorer works the same, with the overlay off and a line that says why.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.errors import DataError
from neuraldem.serve.cache import LruCache
from neuraldem.serve.inputs import NEAR


@dataclass(frozen=True)
class NearRun:
    sim_id: str
    params: dict[str, float]
    metrics: dict[str, float]
    distance: float  # largest parameter difference as a share of its trained range

    def label(self) -> str:
        return f"LIGGGHTS {self.sim_id} ({', '.join(f'{k}={v:.3g}' for k, v in self.params.items())})"


@dataclass(frozen=True)
class StoredTrajectory:
    times: np.ndarray  # (T,) snapshot times
    positions: np.ndarray  # (T, N, 3), NaN once a particle has left
    exit_times: np.ndarray  # (N,), NaN for particles that never leave


class StoredRuns:
    def __init__(self, dataset_dir: Path, records: list[Any], ranges: dict[str, tuple[float, float]],
                 near: float = NEAR):
        self.dataset_dir = Path(dataset_dir)
        self.records = {r.sim_id: r for r in records}
        self.ranges = ranges
        self.near = near
        self._trajectories: LruCache[StoredTrajectory] = LruCache(4)

    @classmethod
    def for_model(cls, meta: dict[str, Any], dataset_dir: Path | None, near: float = NEAR) -> tuple[
            StoredRuns | None, str]:
        """The stored runs of the model's scene, or None and the reason the overlay is off."""
        from neuraldem.data.manifest import MANIFEST_NAME, Manifest
        from neuraldem.paths import data_dir

        name = (meta.get("training_data") or {}).get("dataset")
        if dataset_dir is None and not name:
            return None, "overlay off: the model does not name its dataset (pass dataset=DIR)"
        folder = Path(dataset_dir) if dataset_dir is not None else data_dir() / "datasets" / str(name)
        if not (folder / MANIFEST_NAME).is_file():
            return None, f"overlay off: no stored LIGGGHTS runs at {folder}"
        try:
            m = Manifest.load(folder)
        except DataError as err:
            return None, f"overlay off: {err}"
        if (m.scene or {}).get("hopper") != meta["scene"]["hopper"]:
            return None, f"overlay off: the runs at {folder} are of another hopper scene than the model's"
        inputs = list(meta["inputs"])
        records = [r for r in m.usable() if all(k in r.params for k in inputs) and r.metrics
                   and (folder / str(r.file)).is_file()]
        ranges = {k: tuple(meta["trained_range"][k]) for k in inputs}
        return cls(folder, records, ranges, near), f"{len(records)} stored LIGGGHTS runs at {folder}"

    def nearest(self, values: dict[str, float]) -> NearRun | None:
        """The closest stored run when it is near enough, else None."""
        best: NearRun | None = None
        for rec in self.records.values():
            d = max(abs(values[k] - rec.params[k]) / max(hi - lo, 1e-12) for k, (lo, hi) in self.ranges.items())
            if best is None or d < best.distance:
                best = NearRun(rec.sim_id, {k: float(rec.params[k]) for k in self.ranges}, dict(rec.metrics), d)
        return best if best is not None and best.distance <= self.near else None

    def trajectory(self, sim_id: str) -> StoredTrajectory:
        return self._trajectories.get_or_compute(sim_id, lambda: self._read(sim_id))

    def _read(self, sim_id: str) -> StoredTrajectory:
        from neuraldem.scenes.hopper.dataset.store import HopperFile

        with HopperFile(self.dataset_dir / str(self.records[sim_id].file)) as f:
            return StoredTrajectory(np.asarray(f.times, dtype=np.float64), f.positions(), f.exit_times.copy())

    def particles(self, sim_id: str, t: float, limit: int | None = None) -> tuple[float, np.ndarray]:
        """(snapshot time, positions of the particles still in) at the snapshot nearest `t`; after the run's
        end its last snapshot (the state it held). With `limit`, a fixed random subset of that many particles."""
        traj = self.trajectory(sim_id)
        k = int(np.argmin(np.abs(traj.times - t)))
        pos = traj.positions[k]
        if limit is not None and len(pos) > limit:
            pos = pos[np.sort(np.random.default_rng(0).choice(len(pos), limit, replace=False))]
        return float(traj.times[k]), pos[np.isfinite(pos[:, 0])]

    def remaining(self, sim_id: str, times: np.ndarray) -> np.ndarray:
        """Share of the particles still in the hopper at `times` (from their exit times)."""
        exits = self.trajectory(sim_id).exit_times
        left = np.isfinite(exits)[None, :] & (exits[None, :] <= np.asarray(times)[:, None])
        return 1.0 - left.mean(axis=1)
