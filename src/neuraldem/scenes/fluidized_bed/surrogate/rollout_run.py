"""A bed rollout as a command: from a checkpoint and a first state (a dataset trajectory or a file) to its files
(rollout.h5, rollout.json, a ParaView series); `neuraldem evaluate rollout` runs it."""

from __future__ import annotations

import json
import logging
import warnings
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

from neuraldem import __version__
from neuraldem.config import checks
from neuraldem.data.integrity import ValidatedH5File
from neuraldem.data.schema import SCHEMA_VERSION, atomic_write_h5, atomic_write_json
from neuraldem.errors import DataError
from neuraldem.eval.checkpoints import checkpoint_dataset, read_checkpoint
from neuraldem.eval.vtk_export import write_grid_series, write_point_series
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.normalization import BedNormalizer
from neuraldem.scenes.fluidized_bed.surrogate.option_aliases import RESULT_CONSERVE_KEY
from neuraldem.scenes.fluidized_bed.surrogate.options import RolloutOptions
from neuraldem.scenes.fluidized_bed.surrogate.rollout import (
    DEFAULT_INIT_SNAPSHOT,
    ROLLOUT_KIND,
    DivergenceLimits,
    ExtrapolationWarning,
    ModelStepper,
    Rollout,
    initial_state,
    rollout,
)
from neuraldem.sim.foam_reader import BoxGrid

if TYPE_CHECKING:
    from omegaconf import DictConfig

    from neuraldem.scenes.fluidized_bed.surrogate.module import BedModule  # built by read_checkpoint

log = logging.getLogger(__name__)


def write_rollout(path: Path, r: Rollout, grid: BoxGrid, particle_volume: float, total_volume: float,
                  attrs: dict[str, Any]) -> Path:
    """The rollout as an HDF5 file (module docstring), written atomically."""

    def fill(f: h5py.File) -> None:
        f.attrs.update(schema_version=SCHEMA_VERSION, kind=ROLLOUT_KIND, steps_requested=r.steps_requested,
                       diverged_at=-1 if r.diverged_at is None else r.diverged_at, divergence=r.divergence,
                       neuraldem_version=__version__,
                       created_utc=datetime.now(UTC).isoformat(timespec="seconds"))
        for k, v in attrs.items():
            f.attrs[k] = json.dumps(v) if isinstance(v, (dict, list, tuple)) or v is None else v
        f.create_group("grid").attrs.update(lo=np.asarray(grid.lo), hi=np.asarray(grid.hi),
                                            shape=np.asarray(grid.shape, dtype=np.int64))
        f.create_group("particles").attrs.update(count=r.positions.shape[1], particle_volume=particle_volume,
                                                 total_volume=total_volume)
        s = f.create_group("snapshots")
        s.create_dataset("time", data=r.times)
        cells = tuple(grid.shape)
        for name in ("fluid_velocity", "solid_fraction", "mixing"):
            data = getattr(r, name).astype(np.float32)
            s.create_dataset(name, data=data, chunks=(1, *cells, *data.shape[4:]), compression="gzip")
        g = f.create_group("samples")
        g.create_dataset("time", data=r.sample_times)
        for name in ("positions", "displacement"):
            g.create_dataset("position" if name == "positions" else name,
                             data=getattr(r, name).astype(np.float32), compression="gzip")

    atomic_write_h5(path, fill)
    return path


class RolloutFile(ValidatedH5File):
    """Validating reader of a rollout file; the grid fields read like `BedFile`'s."""

    KIND = ROLLOUT_KIND

    def _read_meta(self) -> None:
        g = self._field("grid").attrs
        self.grid = BoxGrid(lo=tuple(float(v) for v in g["lo"]), hi=tuple(float(v) for v in g["hi"]),
                            shape=tuple(int(v) for v in g["shape"]))  # type: ignore[arg-type]
        p = self._field("particles").attrs
        self.particle_volume = float(p["particle_volume"])
        self.total_volume = float(p["total_volume"])
        self.times = self._field("snapshots/time")[()]
        self.diverged_at = int(self.f.attrs["diverged_at"])
        self.divergence = str(self.f.attrs.get("divergence", ""))
        self.attrs = {k: v for k, v in self.f.attrs.items()}

    def validate(self) -> None:
        T, cells = len(self.times), tuple(self.grid.shape)
        for name, shape in (("fluid_velocity", (T, *cells, 3)), ("solid_fraction", (T, *cells)),
                            ("mixing", (T, *cells))):
            if self._field(f"snapshots/{name}").shape != shape:
                raise DataError(f"{self.path}: /snapshots/{name} has shape {self._field(f'snapshots/{name}').shape}"
                                f", expected {shape}")

    def grid_field(self, name: str) -> np.ndarray:
        return self._field(f"snapshots/{name}")[()].astype(np.float64)


def write_rollout_vtk(folder: Path, name: str, r: Rollout, grid: BoxGrid, every: int = 10) -> list[Path]:
    """ParaView series: the grid fields every `every` steps and the particle samples."""
    checks.positive_int("vtk_every", every)
    idx = list(range(0, len(r.times), every))
    cell_data = [{"solid_fraction": r.solid_fraction[k], "fluid_velocity": r.fluid_velocity[k],
                  "mixing": r.mixing[k]} for k in idx]
    grid_pvd = write_grid_series(folder, f"{name}_grid", r.times[idx], grid.lo, grid.hi, grid.shape, cell_data)
    pts_pvd = write_point_series(folder, f"{name}_particles", r.sample_times, list(r.positions),
                                 [{"displacement": d} for d in r.displacement])
    return [grid_pvd, pts_pvd]


# ---- checkpoints and conditions
def load_fb_checkpoint(path: Path, device: str = "cpu") -> BedModule:
    """A trained fluidized-bed model; a checkpoint of another kind is refused with a message."""
    return read_checkpoint(path).module("fluidized_bed", device, "a fluidized-bed rollout or evaluation")


def check_velocity(norm: BedNormalizer, velocity: float) -> bool:
    """True (and a warning stating the trained range) when `velocity` is outside what the model saw."""
    checks.positive("velocity", velocity)
    if norm.in_trained_range(velocity):
        return False
    msg = (f"inlet velocity {velocity:g} m/s is outside the range the model was trained on "
           f"[{norm.velocity_lo:g}, {norm.velocity_hi:g}] m/s: the rollout extrapolates (flagged in its outputs)")
    warnings.warn(msg, ExtrapolationWarning, stacklevel=2)
    log.warning("%s", msg)
    return True


def check_grid(norm: BedNormalizer, f: BedFile) -> None:
    """The initial state must be on the grid the model was trained on."""
    same_shape = list(f.grid.shape) == list(norm.grid_shape)
    same_box = np.allclose(f.grid.lo, norm.box_lo, atol=1e-9) and np.allclose(f.grid.hi, norm.box_hi, atol=1e-9)
    if not (same_shape and same_box):
        raise DataError(f"{f.path}: grid {list(f.grid.shape)} cells over {list(f.grid.lo)} .. {list(f.grid.hi)} m "
                        f"differs from the model's grid {norm.grid_shape} over {norm.box_lo} .. {norm.box_hi} m: "
                        "start the rollout from a trajectory of the scene the model was trained on")


def initial_file(meta: dict[str, Any], ckpt: Path, velocity: float, datasets_dir: Path,
                 dataset_dir: Path | None = None, init: Path | None = None,
                 init_sim: str | None = None) -> tuple[Path, str]:
    """Where the first state comes from: the given file, else a trajectory of the model's dataset
    (`init_sim`, or the one closest in inlet velocity). Returns (path, description)."""
    if init is not None:
        return Path(init), str(init)
    dataset_dir, m = checkpoint_dataset(meta, Path(ckpt), datasets_dir, dataset_dir)
    if init_sim is not None:
        rec = m.record(init_sim)
        if not rec.usable:
            raise DataError(f"simulation {init_sim} of {dataset_dir} is not finished (status {rec.status})")
    else:
        rec = min(m.usable(), key=lambda r: (abs(r.params.get("inlet_velocity", np.inf) - velocity), r.sim_id))
    return dataset_dir / str(rec.file), f"{m.name}/{rec.sim_id}"


def run_rollout(ckpt: Path, velocity: float, steps: int, out_dir: Path, datasets_dir: Path,
                dataset_dir: Path | None = None, init: Path | None = None, init_sim: str | None = None,
                init_snapshot: int = DEFAULT_INIT_SNAPSHOT, seed: int = 0, limits: DivergenceLimits | None = None,
                particles_every: int = 10, vtk: bool = True, vtk_every: int = 10, device: str = "cpu",
                progress: bool = True, options: RolloutOptions | None = None) -> dict[str, Any]:
    """Load, roll out, write rollout.h5 (+ vtk/, rollout.json) into `out_dir`; return the summary."""
    checks.positive_int("steps", steps)
    limits = limits or DivergenceLimits()
    module = load_fb_checkpoint(ckpt, device)
    meta, norm = module.metadata, module.norm
    extrapolation = check_velocity(norm, velocity)
    path, source = initial_file(meta, Path(ckpt), velocity, datasets_dir, dataset_dir, init, init_sim)
    with BedFile(path) as f:
        check_grid(norm, f)
        state = initial_state(f, init_snapshot)
        present = np.isfinite(f.positions(init_snapshot)).all(axis=1)
        volumes = f.particle_volumes[present]
        grid = f.grid
    stepper = ModelStepper(module, velocity, seed, device, options)
    r = rollout(stepper, state, steps, limits, particles_every, progress)
    summary = {
        "checkpoint": str(Path(ckpt).resolve()), "data_name": meta["data_name"], "inlet_velocity": float(velocity),
        "extrapolation": extrapolation, "trained_velocity_range": [norm.velocity_lo, norm.velocity_hi],
        "initial_state": f"{source} snapshot {init_snapshot}", "seed": seed, "max_packing": limits.max_packing,
        "tolerance": limits.tolerance, "dt": norm.dt, "training_horizon_steps": norm.horizon_steps,
        RESULT_CONSERVE_KEY: stepper.stability.conserve_volume, "mixing": stepper.stability.mixing,
        "mirror_alternate": stepper.stability.mirror_alternate, "rollout_noise": stepper.stability.rollout_noise,
        "advection_correction": stepper.stability.advection_correction,
    }
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_rollout(out_dir / "rollout.h5", r, grid, float(volumes.mean()), float(volumes.sum()), summary)
    if vtk:
        write_rollout_vtk(out_dir / "vtk", "rollout", r, grid, vtk_every)
    summary |= {"steps_requested": steps, "steps_done": r.steps_done,
                "diverged_at": r.diverged_at, "divergence": r.divergence, "message": r.message(),
                "files": {"hdf5": str(out_dir / "rollout.h5"), "vtk": str(out_dir / "vtk") if vtk else None}}
    atomic_write_json(out_dir / "rollout.json", summary)
    return summary


def rollout_command(cfg: DictConfig) -> bool:
    """`neuraldem evaluate rollout ckpt=... velocity=... steps=...` for a bed checkpoint (conf/rollout.yaml, the
    rollout options under `rollout.*`); False when the rollout diverged."""
    from neuraldem.eval.checkpoints import resolve_device

    checks.required(cfg, "rollout", {"ckpt": "ckpt=<run>/checkpoints/last.ckpt", "velocity": "velocity=1.6"})
    checks.one_of("device", cfg.device, ("auto", "cpu", "cuda"))
    limits = DivergenceLimits(checks.number("max_packing", cfg.max_packing, lo=0.0, hi=1.0, lo_open=True),
                              checks.number("tolerance", cfg.tolerance, lo=0.0, hi=0.5))
    options = RolloutOptions.from_config(cfg.get("rollout"))
    summary = run_rollout(
        Path(cfg.ckpt), checks.positive("velocity", cfg.velocity), checks.positive_int("steps", cfg.steps),
        out_dir=Path(cfg.paths.output_dir), datasets_dir=Path(cfg.paths.datasets_dir),
        dataset_dir=cfg.dataset_dir, init=cfg.init, init_sim=cfg.init_sim, init_snapshot=cfg.init_snapshot,
        seed=checks.positive_int("seed", cfg.seed, allow_zero=True), limits=limits,
        particles_every=cfg.particles_every, vtk=bool(cfg.vtk), vtk_every=cfg.vtk_every,
        device=resolve_device(cfg.device), progress=bool(cfg.progress), options=options)
    print(summary["message"])
    if summary["extrapolation"]:
        lo, hi = summary["trained_velocity_range"]
        print(f"note: {cfg.velocity} m/s is outside the trained range [{lo:g}, {hi:g}] m/s (extrapolation)")
    print(f"results in {cfg.paths.output_dir}")
    return summary["diverged_at"] is None
