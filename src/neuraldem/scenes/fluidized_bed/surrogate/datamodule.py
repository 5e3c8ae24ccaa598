"""BedDataModule: next-step samples (state at t -> fields at t + k dt) streamed from the HDF5 files.

A sample, in model units (`BedNormalizer`, fitted on the training trajectories only):
- inputs at t: particle positions and their last displacement (t-1 -> t; zero at t = 0) for the particle
  branch (supernode pooling), fluid velocity + solid fraction on the grid for the fluid branch (patches),
  mixing concentration on the grid for the off-branch, the inlet velocity as conditioning scalar;
- targets at every t + k, k = 1 .. K: the fluid velocity, solid fraction (and solids flux) and mixing on the
  grid, and the particle displacement (t+k-1 -> t+k) at the particle positions of t + k. The particle branch
  thus predicts the same quantity it reads (the displacement field that brought particles where they are),
  which is what a field-based rollout needs: it decodes that field at positions sampled from the predicted
  solid fraction;
- the solid volume of the state at t (sum of its solid fraction over the cells), for the volume projection.

K = `push_forward_steps` (training split only) is the longest unroll the LightningModule may draw: it rolls
itself forward from t and is scored on every step it takes (`neuraldem.scenes.fluidized_bed.surrogate.options`), so it
learns
from inputs that carry its own errors; `input_noise` adds Gaussian noise of that std (in model units) to the
training inputs for the same purpose. Validation and test always use K = 1 and no noise, so their losses
compare across these options.

`mirror=true` (training split only) serves the mirror image in x of half the samples, drawn per sample
(`neuraldem.scenes.fluidized_bed.surrogate.mirror`: the bed is left-right symmetric, so the image is another trajectory
of the same physics).

`solids_flux=true` adds three grid channels: the kernel solids flux alpha_p u_s of the last step (a two-fluid
state: the fluid branch then sees and predicts how the solid moves, which the conservative mixing advection
uses).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import torch

from neuraldem.config import checks
from neuraldem.data.file_samples import FileSamples
from neuraldem.data.manifest import Manifest, SimRecord, require_dataset
from neuraldem.data.part_loaders import PartLoaders
from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes.fluidized_bed.dataset.store import KIND, BedFile
from neuraldem.scenes.fluidized_bed.surrogate.mirror import mirror_grid, mirror_points, mirror_vectors
from neuraldem.scenes.fluidized_bed.surrogate.normalization import BedNormalizer, grid_input, mixing_input

log = logging.getLogger(__name__)

CONDITIONING_NAMES = ("inlet_velocity",)
SPLITS = ("velocity",)
MAX_PUSH_FORWARD = 64
MAX_INPUT_NOISE = 1.0  # model units (one standard deviation of the data)


class BedSamples(FileSamples):
    """All (trajectory, t) samples with t + steps inside the trajectory (every `time_stride`-th t)."""

    def __init__(self, dataset_dir: Path, records: list[SimRecord], norm: BedNormalizer, steps: int,
                 particles_per_sample: int | None, input_noise: float, random: bool, seed: int = 0,
                 time_stride: int = 1, solids_flux: bool = False, mirror: bool = False):
        self.dir = Path(dataset_dir)
        self.solids_flux = solids_flux
        self.mirror = mirror
        self.records = records
        self.norm = norm
        self.steps = steps
        self.n_particles = particles_per_sample
        self.noise = input_noise
        self.items = []
        for s, rec in enumerate(records):
            with BedFile(self.dir / str(rec.file), validate=False) as f:
                n_snapshots = f.n_snapshots
            self.items += [(s, t) for t in range(0, n_snapshots - steps, time_stride)]
        super().__init__(random, seed)

    def __len__(self) -> int:
        return len(self.items)

    def _open_file(self, s: int) -> BedFile:
        return BedFile(self.dir / str(self.records[s].file), validate=False)  # validated in setup()

    def _pick(self, rng: np.random.Generator, ok: np.ndarray, n: int) -> np.ndarray:
        """Indices of n particles of a sample: all present ones (n of them), or a random subset."""
        present = np.flatnonzero(ok)
        if n == len(present):
            return present
        return np.sort(rng.choice(present, n, replace=len(present) < n))

    def _grid(self, f: BedFile, t: int, flip: bool = False) -> np.ndarray:
        # the whole trajectory's flux, computed once per open file and kept (not one deposit per sample)
        flux = f.solids_flux()[t] if self.solids_flux else None
        velocity, alpha = f.fluid_velocity(t), f.solid_fraction(t)
        if flip:
            velocity, alpha = mirror_grid(velocity, vector=True), mirror_grid(alpha, vector=False)
            flux = None if flux is None else mirror_grid(flux, vector=True)
        return grid_input(self.norm, velocity, alpha, flux)

    def _mixing(self, f: BedFile, t: int, flip: bool) -> np.ndarray:
        c = f.mixing(t)
        return mixing_input(self.norm, mirror_grid(c, vector=False) if flip else c)

    def sample(self, i: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
        s, t = self.items[i]
        f = self._open(s)
        norm = self.norm
        flip = self.mirror and bool(rng.random() < 0.5)  # no draw without mirror: the old sample streams stay
        lo_x, hi_x = f.grid.lo[0], f.grid.hi[0]

        def points(p: np.ndarray) -> np.ndarray:
            return mirror_points(p, lo_x, hi_x) if flip else p

        def vectors(v: np.ndarray) -> np.ndarray:
            return mirror_vectors(v) if flip else v

        pos = points(f.positions(t))
        disp_in = vectors(f.displacement(t - 1)) if t > 0 else np.zeros_like(pos)
        ok_in = np.isfinite(pos).all(axis=1) & np.isfinite(disp_in).all(axis=1)
        n = self.n_particles or int(ok_in.sum())
        p_in = self._pick(rng, ok_in, n)
        features = norm.field("displacement", disp_in[p_in])
        grid = self._grid(f, t, flip)
        mixing = self._mixing(f, t, flip)
        solid_volume = float(np.sum(f.solid_fraction(t)))
        if self.noise > 0:
            features, grid, mixing = (x + self.noise * rng.standard_normal(x.shape) for x in (features, grid, mixing))
        targets: dict[str, list[np.ndarray]] = {"pos": [], "particles": [], "fluid": [], "mixing": []}
        for tk in range(t + 1, t + self.steps + 1):
            pos_k, disp_k = points(f.positions(tk)), vectors(f.displacement(tk - 1))
            p_out = self._pick(rng, np.isfinite(pos_k).all(axis=1) & np.isfinite(disp_k).all(axis=1), n)
            targets["pos"].append(norm.positions(pos_k[p_out]))
            targets["particles"].append(norm.field("displacement", disp_k[p_out]))
            fluid = np.moveaxis(self._grid(f, tk, flip), 0, -1)
            targets["fluid"].append(fluid.reshape(-1, fluid.shape[-1]))
            targets["mixing"].append(np.moveaxis(self._mixing(f, tk, flip), 0, -1).reshape(-1, 1))
        velocity = self.records[s].params.get("inlet_velocity", f.inlet_velocity)

        def tensor(x: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))

        return {
            "scalars": tensor(np.array([norm.velocity(velocity)])),
            "particle_pos": tensor(norm.positions(pos[p_in])),
            "particle_features": tensor(features),
            "grid": tensor(grid),
            "mixing_grid": tensor(mixing),
            "solid_volume": torch.tensor(solid_volume, dtype=torch.float64),
            **{f"target_{k}": tensor(np.stack(v)) for k, v in targets.items()},  # (K, ...) per step
        }


class BedDataModule(PartLoaders):
    """Train/val/test loaders over a fluidized-bed dataset dir, split by inlet velocity (manifest)."""

    def __init__(self, dataset_dir: str, name: str, conditioning: list[str] | None = None,
                 split: str = "velocity", batch_size: int = 8, particles_per_sample: int | None = None,
                 input_noise: float = 0.0, push_forward_steps: int = 1, num_workers: int = 0, seed: int = 0,
                 eval_time_stride: int = 1, solids_flux: bool = False, mirror: bool = False,
                 runs_from: str | None = None):
        super().__init__()
        self.runs_from = None if runs_from in (None, "") else Path(str(runs_from))
        self.run_ids: dict[str, list[str]] | None = None
        self.solids_flux = checks.boolean("data.datamodule.solids_flux", solids_flux)
        self.mirror = checks.boolean("data.datamodule.mirror", mirror)
        self.dataset_dir = Path(dataset_dir)
        self.name = name
        self.conditioning = checks.names("data.conditioning", list(conditioning or CONDITIONING_NAMES),
                                         allowed=CONDITIONING_NAMES)
        self.split = checks.one_of("data.split", split, SPLITS)
        self.batch_size = checks.positive_int("data.datamodule.batch_size", batch_size)
        if particles_per_sample is not None:
            checks.positive_int("data.datamodule.particles_per_sample", particles_per_sample)
        self.particles_per_sample = particles_per_sample
        self.input_noise = checks.number("data.datamodule.input_noise", input_noise, lo=0.0, hi=MAX_INPUT_NOISE)
        self.push_forward_steps = checks.positive_int("data.datamodule.push_forward_steps", push_forward_steps)
        if self.push_forward_steps > MAX_PUSH_FORWARD:
            raise ConfigError(f"config value data.datamodule.push_forward_steps={push_forward_steps} is invalid: "
                              f"must be <= {MAX_PUSH_FORWARD} (each step is a forward pass per sample; 2-4 is "
                              "typical) (override it, e.g. data.datamodule.push_forward_steps=2)")
        self.num_workers = checks.positive_int("data.datamodule.num_workers", num_workers, allow_zero=True)
        self.seed = checks.positive_int("data.datamodule.seed", seed, allow_zero=True)
        self.eval_time_stride = checks.positive_int("data.datamodule.eval_time_stride", eval_time_stride)
        self.manifest: Manifest | None = None
        self.norm: BedNormalizer | None = None
        self.datasets: dict[str, BedSamples] = {}

    @property
    def scene(self) -> dict[str, Any]:
        assert self.manifest is not None
        return self.manifest.scene

    def records(self, part: str) -> list[SimRecord]:
        assert self.manifest is not None
        ids = self.manifest.split_ids(self.split, part) if self.run_ids is None else self.run_ids[part]
        return [self.manifest.record(i) for i in ids]

    def paths(self, part: str) -> list[Path]:
        return [self.dataset_dir / str(r.file) for r in self.records(part)]

    def prepare_manifest(self) -> Manifest:
        if self.manifest is None:
            m = require_dataset(self.dataset_dir, self.name)
            if m.kind != KIND:
                raise DataError(f"dataset {self.dataset_dir} holds {m.kind!r} data, not {KIND} data: pick a "
                                "fluidized-bed dataset (e.g. data=fb_small)")
            if not m.splits.get(self.split, {}).get("train"):
                raise DataError(f"dataset {self.dataset_dir}: split {self.split!r} has no training trajectories; "
                                f"generate more with python -m neuraldem.datagen data={self.name} n_sims=N")
            if self.runs_from is not None:
                self.run_ids = recorded_runs(self.runs_from, m, self.split)
            self.manifest = m
        return self.manifest

    def setup(self, stage: str | None = None) -> None:
        if self.datasets:
            return
        self.prepare_manifest()
        if self.norm is None:
            self.norm = BedNormalizer.fit(self.paths("train"), self.solids_flux)  # validates every training file
        for part in ("val", "test"):
            for path in self.paths(part):
                BedFile(path).close()  # validate once, up front
        if not self.records("val"):
            log.warning("dataset %s: split %r has no validation trajectories; training runs without "
                        "validation", self.dataset_dir, self.split)
        self._check_push_forward()
        for part in ("train", "val", "test"):
            train = part == "train"
            self.datasets[part] = BedSamples(
                self.dataset_dir, self.records(part), self.norm, self.push_forward_steps if train else 1,
                self.particles_per_sample, self.input_noise if train else 0.0, random=train, seed=self.seed,
                time_stride=1 if train else self.eval_time_stride, solids_flux=self.solids_flux,
                mirror=self.mirror and train)

    def _check_push_forward(self) -> None:
        lengths = []
        for path in self.paths("train"):
            with BedFile(path, validate=False) as f:
                lengths.append(f.n_snapshots - 1)
        shortest = min(lengths)
        if self.push_forward_steps > shortest:
            raise ConfigError(f"config value data.datamodule.push_forward_steps={self.push_forward_steps} is "
                              f"invalid: the shortest training trajectory of {self.dataset_dir} has {shortest} "
                              "steps (override it, e.g. data.datamodule.push_forward_steps=2)")

    def checkpoint_metadata(self) -> dict[str, Any]:
        """What a rollout and the evaluation need to use a trained model correctly (in every checkpoint)."""
        assert self.manifest is not None and self.norm is not None
        return {"kind": KIND, "data_name": self.name, "scene": self.scene, "conditioning": self.conditioning,
                "split": self.split, "normalizer": self.norm.to_dict(),
                "train_velocities": sorted({float(r.params["inlet_velocity"]) for r in self.records("train")}),
                # the runs of each part when it trained: the dataset may grow later (what a shipped model records)
                "split_ids": {p: [r.sim_id for r in self.records(p)] for p in ("train", "val", "test")},
                "push_forward_steps": self.push_forward_steps, "input_noise": self.input_noise,
                "solids_flux": self.solids_flux, "mirror": self.mirror, "grid_channels": 7 if self.solids_flux else 4,
                "particles_per_sample": self.particles_per_sample}


def recorded_runs(path: Path, manifest: Manifest, split: str) -> dict[str, list[str]]:
    """The runs of each part that a checkpoint trained on (its metadata's `split_ids`), or of a JSON file
    {"train": [...], "val": [...], "test": [...]}: so a new run repeats an earlier one's data while the dataset
    grows (a paired ablation). Every run must be finished in `manifest` and belong to the same part of `split`
    there (a part never borrows another's runs)."""
    key = "data.datamodule.runs_from"
    if not path.is_file():
        raise ConfigError(f"config value {key}={path} is invalid: no such file (give a checkpoint of the run whose "
                          "data to repeat, or a JSON file of its train/val/test run ids; or null)")
    try:
        if path.suffix == ".json":
            ids = json.loads(path.read_text())
        else:
            raw = torch.load(path, map_location="cpu", weights_only=False, mmap=True)
            ids = raw["hyper_parameters"]["metadata"]["split_ids"]
    except Exception as err:  # noqa: BLE001 - any unreadable file or one without the record
        raise ConfigError(f"config value {key}={path} is invalid: it holds no run ids per part "
                          f"({type(err).__name__}: {err}); give a checkpoint trained since split_ids were "
                          'recorded or a JSON file {"train": [...], "val": [...], "test": [...]}') from None
    out = {}
    for part in ("train", "val", "test"):
        wanted = ids.get(part) if isinstance(ids, dict) else None
        if not isinstance(wanted, list) or (part == "train" and not wanted):
            raise ConfigError(f"config value {key}={path} is invalid: no list of {part!r} run ids in it")
        allowed = set(manifest.split_ids(split, part))
        for sim_id in wanted:
            if sim_id not in allowed:
                raise DataError(f"{path}: run {sim_id!r} ({part}) is not a finished {part} run of split {split!r} "
                                f"in dataset {manifest.name!r}: generate it (python -m neuraldem.datagen "
                                f"data={manifest.name}) or set {key}=null")
        out[part] = [str(i) for i in wanted]
    return out

