"""ExportGnsDataModule: the GNS baseline (`gns.datamodule`) trained from an export instead of a dataset.

Reads a folder written by `neuraldem export` (either format; `formats.read_export`): positions, types, dt and
the box (`bounds`) from its files and metadata.json, the conditioning scalars of each trajectory from the
metadata's `neuraldem` section, the training/validation/test parts from its split files. Particles that an
export "holds" after they left are absent again here (the exit steps beside the split files), so the samples
are those `GnsDataModule` makes from the dataset itself, but with the walls seen only as the box: an export
carries no scene geometry (no hopper cone or cylinder distances, `n_extra_walls` 0). Normalisation statistics
are fitted on the export's training part, as `GnsDataModule` does on the dataset's.

Checkpoints carry `export` (the folder and format) in their metadata; the rollout tools, which replay stored
runs with the scene's walls, refuse them.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.config import checks
from neuraldem.data.file_samples import FileSamples
from neuraldem.errors import ConfigError, DataError
from neuraldem.export.formats import Export, Trajectory, read_export
from neuraldem.gns.datamodule import CONDITIONING, SCENES, GnsLoaders, GnsNormalizer, GnsSamples

log = logging.getLogger(__name__)


class ExportRun:
    """One exported trajectory as `GnsSamples` reads a run: positions with NaN where a particle is gone, and
    the box as the only walls."""

    geometry = None

    def __init__(self, traj: Trajectory, box_lo: np.ndarray, box_hi: np.ndarray):
        self.traj, self.box_lo, self.box_hi = traj, box_lo, box_hi

    @property
    def n_snapshots(self) -> int:
        return self.traj.n_snapshots

    def positions(self, t: slice = slice(None)) -> np.ndarray:
        return self.traj.physical(t)

    def close(self) -> None:
        pass


class ExportSamples(GnsSamples):
    """`GnsSamples` over exported trajectories (held in memory as the export stores them, float32)."""

    def __init__(self, runs: list[ExportRun], norm: GnsNormalizer, noise_std: float, random: bool, seed: int = 0,
                 time_stride: int = 1):
        self.runs, self.norm, self.noise_std = runs, norm, noise_std
        h = norm.history
        self.items = [(s, t) for s, run in enumerate(runs) for t in range(h, run.n_snapshots - 1, time_stride)]
        FileSamples.__init__(self, random, seed)

    def _open_file(self, s: int) -> ExportRun:  # type: ignore[override]
        return self.runs[s]

    def conditioning(self, s: int) -> dict[str, float]:
        return self.runs[s].traj.conditioning


class ExportGnsDataModule(GnsLoaders):
    """Train/val/test loaders of one-step GNS samples from an export folder."""

    def __init__(self, export_dir: str, conditioning: list[str] | None = None, history: int = 5,
                 noise_std: float = 0.0, batch_size: int = 2, num_workers: int = 0, seed: int = 0,
                 eval_time_stride: int = 1):
        super().__init__(conditioning, history, noise_std, batch_size, num_workers, seed, eval_time_stride)
        self.export_dir = Path(export_dir).expanduser()
        self.export: Export | None = None
        self.datasets: dict[str, ExportSamples] = {}

    @property
    def kind(self) -> str:
        assert self.export is not None
        return self.export.kind

    @property
    def conditioning(self) -> list[str]:
        return self._conditioning_of(self.kind)

    def _conditioning_of(self, kind: str) -> list[str]:
        return list(self._conditioning) if self._conditioning is not None else list(CONDITIONING[kind][:3])

    def prepare_manifest(self) -> Export:
        """The export (read once), checked: a scene the GNS knows, conditioning scalars every trajectory has."""
        if self.export is None:
            e = read_export(self.export_dir)
            if e.kind not in SCENES:
                raise DataError(f"export {self.export_dir} holds {e.kind!r} data; the GNS baseline reads "
                                f"{list(SCENES)} data")
            conditioning = checks.names("data.conditioning", self._conditioning_of(e.kind),
                                        allowed=CONDITIONING[e.kind])
            if not e.parts["train"]:
                raise DataError(f"export {self.export_dir} has no training trajectories",
                                "export a split with training runs (neuraldem export ... split=...)")
            for traj in (t for part in e.parts.values() for t in part):
                missing = [n for n in conditioning if n not in traj.conditioning]
                if missing:
                    raise DataError(f"export {self.export_dir}: trajectory {traj.sim_id} has no conditioning "
                                    f"scalar {missing[0]!r}", "choose data.conditioning from what it has: "
                                    + ", ".join(sorted(traj.conditioning)))
            self.export = e
        return self.export

    def setup(self, stage: str | None = None) -> None:
        if self.datasets:
            return
        e = self.prepare_manifest()
        lo, hi = e.box
        dt, diameter = float(e.metadata["dt"]), float(e.info["particle_diameter"])
        runs = {part: [ExportRun(t, lo, hi) for t in trajs] for part, trajs in e.parts.items()}
        if self.norm is None:
            self.norm = GnsNormalizer.from_trajectories(
                ((r.positions(), dt, diameter) for r in runs["train"]), [t.conditioning for t in e.parts["train"]],
                e.kind, self.history, self.conditioning)
        if not runs["val"]:
            log.warning("export %s has no validation trajectories; training runs without validation",
                        self.export_dir)
        for part, part_runs in runs.items():
            train = part == "train"
            self.datasets[part] = ExportSamples(part_runs, self.norm, self.noise_std if train else 0.0,
                                                random=train, seed=self.seed,
                                                time_stride=1 if train else self.eval_time_stride)
        if not len(self.datasets["train"]):
            raise ConfigError(f"config value data.datamodule.history={self.history} is invalid: no training "
                              f"trajectory of {self.export_dir} has {self.history + 2} snapshots (override it, e.g. "
                              "data.datamodule.history=2)")

    def checkpoint_metadata(self) -> dict[str, Any]:
        """As `GnsDataModule.checkpoint_metadata`, with no scene walls and the export it came from."""
        assert self.export is not None and self.norm is not None
        info = self.export.info
        meta = {"kind": "gns", "scene_kind": self.kind, "data_name": info["dataset"], "scene": info["scene"],
                "conditioning": self.conditioning, "split": info["split"], "normalizer": self.norm.to_dict(),
                "history": self.history, "n_extra_walls": 0, "noise_std": self.noise_std,
                "export": {"dir": str(self.export_dir.resolve()), "format": self.export.format,
                           "exits": info["exits"]}}
        if self.kind == "fluidized_bed":
            meta["train_velocities"] = sorted({t.conditioning["inlet_velocity"] for t in self.export.parts["train"]
                                               if "inlet_velocity" in t.conditioning})
        return meta
