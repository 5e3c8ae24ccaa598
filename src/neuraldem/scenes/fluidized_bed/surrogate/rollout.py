"""Autoregressive, field-based rollout of a fluidized-bed model, with divergence detection, HDF5 and VTK output.

Each step feeds the model its own previous prediction: the decoded fluid velocity, solid fraction and mixing
grids, and particles re-sampled from the predicted solid fraction with the decoded displacement field at
their positions (`neuraldem.scenes.fluidized_bed.surrogate.autoregressive`, the same step push-forward training takes).
Particles are never tracked. The first state is a snapshot of a stored trajectory (positions, last displacement,
fields).

Every new state is checked; NaN/inf anywhere, or a solid fraction below -tolerance or above max_packing +
tolerance, stops the rollout and names the step. The states before it are kept and written.

Rollout file (kind "fluidized_bed_rollout"): the grid fields under the ground truth's names, so the same
metric code reads both:
  attrs: schema_version, kind, checkpoint, data_name, inlet_velocity, extrapolation, trained_velocity_range,
         steps_requested, diverged_at (-1 = never), divergence, initial_state, seed, max_packing, tolerance,
         created_utc, neuraldem_version
  /grid                          attrs lo, hi, shape (as in the dataset files)
  /particles                     attrs count, particle_volume (mean) [m^3], total_volume [m^3] (of the
                                 initial state; what the solid fraction should integrate to)
  /snapshots/time                (T,) [s], T = steps done + 1 (the initial state is snapshot 0)
  /snapshots/fluid_velocity      (T, nx, ny, nz, 3); solid_fraction, mixing (T, nx, ny, nz)
  /samples/time                  (S,) every `particles_every`-th snapshot
  /samples/position, /samples/displacement  (S, N, 3) the sampled particle inputs (not tracked particles)
"""

from __future__ import annotations

import json
import logging
import warnings
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import h5py
import numpy as np
import torch
from tqdm import tqdm

from neuraldem import __version__
from neuraldem.config import checks
from neuraldem.data.integrity import ValidatedH5File
from neuraldem.data.schema import SCHEMA_VERSION, atomic_write_h5, atomic_write_json
from neuraldem.errors import ConfigError, DataError
from neuraldem.eval.checkpoints import checkpoint_dataset, read_checkpoint
from neuraldem.eval.vtk_export import write_grid_series, write_point_series
from neuraldem.models.multi_branch_operator import OperatorInputs
from neuraldem.scenes.fluidized_bed.dataset.store import FbFile
from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import advance, perturb_inputs
from neuraldem.scenes.fluidized_bed.surrogate.datamodule import grid_input, mixing_input
from neuraldem.scenes.fluidized_bed.surrogate.mirror import mirror_grid, mirror_points, mirror_vectors
from neuraldem.scenes.fluidized_bed.surrogate.module import FluidizedBedModule
from neuraldem.scenes.fluidized_bed.surrogate.normalization import FbNormalizer
from neuraldem.scenes.fluidized_bed.surrogate.options import FbStability, rollout_overrides
from neuraldem.sim.foam_reader import BoxGrid

if TYPE_CHECKING:
    from omegaconf import DictConfig

log = logging.getLogger(__name__)

ROLLOUT_KIND = "fluidized_bed_rollout"
DEFAULT_MAX_PACKING = 0.74  # densest packing of equal spheres; the kernel field of the data reaches ~0.72
DEFAULT_TOLERANCE = 0.05
ROUND_OFF = 1e-4  # relative volume error a float32 projection leaves


class ExtrapolationWarning(UserWarning):
    """The model is asked about an inlet velocity outside the range it was trained on."""


@dataclass
class FbState:
    """The model's input at one time, in physical units."""

    time: float
    positions: np.ndarray  # (N, 3) [m] particle input positions (data or sampled)
    displacement: np.ndarray  # (N, 3) [m] displacement that brought them there
    fluid_velocity: np.ndarray  # (nx, ny, nz, 3) [m/s]
    solid_fraction: np.ndarray  # (nx, ny, nz)
    mixing: np.ndarray  # (nx, ny, nz)
    solids_flux: np.ndarray | None = None  # (nx, ny, nz, 3) [m/s] of the last step (models trained with it)


DEFAULT_INIT_SNAPSHOT = 1  # snapshot 0 has no last displacement (zero), which training almost never sees


def initial_state(f: FbFile, snapshot: int = DEFAULT_INIT_SNAPSHOT, key: str = "init_snapshot") -> FbState:
    """Snapshot `snapshot` of a stored trajectory as a rollout's first state (absent particles dropped)."""
    if isinstance(snapshot, bool) or not isinstance(snapshot, int) or not 0 <= snapshot < f.n_snapshots:
        raise ConfigError(f"config value {key}={snapshot!r} is invalid: {f.path} has snapshots 0 .. "
                          f"{f.n_snapshots - 1} (override it, e.g. {key}={DEFAULT_INIT_SNAPSHOT})")
    pos = f.positions(snapshot)
    disp = f.displacement(snapshot - 1) if snapshot > 0 else np.zeros_like(pos)
    ok = np.isfinite(pos).all(axis=1) & np.isfinite(disp).all(axis=1)
    return FbState(time=float(f.times[snapshot]), positions=pos[ok], displacement=disp[ok],
                   fluid_velocity=f.fluid_velocity(snapshot), solid_fraction=f.solid_fraction(snapshot),
                   mixing=f.mixing(snapshot), solids_flux=f.solids_flux(snapshot))


def mirror_state(s: FbState, lo_x: float, hi_x: float) -> FbState:
    """The state of the bed mirrored at its mid-plane in x (an involution: applied twice, the state itself)."""
    return FbState(time=s.time, positions=mirror_points(s.positions, lo_x, hi_x),
                   displacement=mirror_vectors(s.displacement),
                   fluid_velocity=mirror_grid(s.fluid_velocity, vector=True),
                   solid_fraction=mirror_grid(s.solid_fraction, vector=False),
                   mixing=mirror_grid(s.mixing, vector=False),
                   solids_flux=None if s.solids_flux is None else mirror_grid(s.solids_flux, vector=True))


@dataclass
class DivergenceLimits:
    max_packing: float = DEFAULT_MAX_PACKING
    tolerance: float = DEFAULT_TOLERANCE

    def __post_init__(self) -> None:
        checks.number("max_packing", self.max_packing, lo=0.0, hi=1.0, lo_open=True)
        checks.number("tolerance", self.tolerance, lo=0.0, hi=0.5)

    def problem(self, s: FbState) -> str | None:
        """Why a state is unphysical (None if it is fine)."""
        for name in ("fluid_velocity", "solid_fraction", "mixing", "displacement", "positions"):
            bad = ~np.isfinite(getattr(s, name))
            if bad.any():
                return f"NaN/inf in the predicted {name.replace('_', ' ')} ({int(bad.sum())} values)"
        a = s.solid_fraction
        if a.min() < -self.tolerance:
            cell = np.unravel_index(int(a.argmin()), a.shape)
            return (f"solid fraction {a.min():.3g} below 0 (tolerance {self.tolerance}) in cell "
                    f"{tuple(int(c) for c in cell)}")
        if a.max() > self.max_packing + self.tolerance:
            cell = np.unravel_index(int(a.argmax()), a.shape)
            return (f"solid fraction {a.max():.3g} above the maximum packing {self.max_packing} (+ tolerance "
                    f"{self.tolerance}) in cell {tuple(int(c) for c in cell)}")
        return None


class Stepper(Protocol):
    dt: float

    def step(self, state: FbState) -> FbState: ...


class ModelStepper:
    """A trained FluidizedBedModule as a stepper, conditioned on one inlet velocity.

    The step applies the checkpoint's stability options (`neuraldem.scenes.fluidized_bed.surrogate.options`), which
    `mixing` and
    `conserve_solid_volume` override (None = the checkpoint's): with volume conservation the predicted solid
    fraction is clamped >= 0 and scaled to the solid volume of the first state it was given (the bed is closed:
    CFD-DEM loses no particle), so the rollout holds it to round-off. A model trained without it and rolled
    out with it is a projection on top of the model: its drift is then 0 by construction and says nothing of
    the model's own conservation. A stochastic model draws its latent noise from this stepper's generator.
    With `mirror_alternate` every second step is taken in the mirror image of the bed, with `rollout_noise` the
    net reads a perturbed copy of each state (`FbStability`; both drawn from this stepper's generator)."""

    def __init__(self, module: FluidizedBedModule, velocity: float, seed: int = 0, device: str = "cpu",
                 conserve_solid_volume: bool | None = None, mixing: str | None = None,
                 advection_correction: float | None = None, advection_flux: str | None = None,
                 mirror_alternate: bool | None = None, rollout_noise: float | None = None):
        base = getattr(module, "stability", None) or FbStability()
        self.stability = rollout_overrides(base, mixing, conserve_solid_volume, advection_correction, advection_flux,
                                           mirror_alternate, rollout_noise)
        self.noise_std = perturbation_std(module, self.stability.rollout_noise, device)
        self.steps_taken = 0
        if self.stability.mixing == "advect" and not module.metadata.get("solids_flux", False):
            raise ConfigError("config value mixing=advect needs a model trained with the solids flux "
                              "(data.datamodule.solids_flux=true): use mixing=absolute for this checkpoint")
        self.conserve_solid_volume = self.stability.conserve_volume
        self.solid_volume: float | None = None  # sum of the first state's solid fraction (cells are equal)
        self.net = module.net.to(device).eval()
        self.step_scales = getattr(module, "step_scales", None)  # a residual model's
        self.norm: FbNormalizer = module.norm
        self.solids_flux = bool(module.metadata.get("solids_flux", False))
        self.dt = self.norm.dt
        self.chunk_size = module.chunk_size
        self.device = device
        self.scalars = torch.tensor([[self.norm.velocity(velocity)]], dtype=torch.float32, device=device)
        self.generator = torch.Generator(device=device).manual_seed(int(seed))

    def _tensor(self, x: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))[None].to(self.device)

    def step(self, state: FbState) -> FbState:
        mirrored = self.stability.mirror_alternate and self.steps_taken % 2 == 1
        self.steps_taken += 1
        if not mirrored:
            return self._step(state)
        lo_x, hi_x = self.norm.box_lo[0], self.norm.box_hi[0]
        return mirror_state(self._step(mirror_state(state, lo_x, hi_x)), lo_x, hi_x)

    # inference_mode, not just no_grad: no version counters or view tracking (bench fb_speed on the shipped net:
    # 0.832 -> 0.791 s per simulated second at one thread, fields bit-identical)
    @torch.inference_mode()
    def _step(self, state: FbState) -> FbState:
        norm = self.norm
        if self.solid_volume is None:
            self.solid_volume = float(np.sum(state.solid_fraction))
        flux = state.solids_flux if self.solids_flux else None
        if self.solids_flux and flux is None:
            raise DataError("this model reads the solids flux: start the rollout from a dataset trajectory "
                            "(initial_state computes it)")
        noise = None
        if self.net.noise_dim:
            noise = torch.randn(1, self.net.noise_dim, generator=self.generator, device=self.device)
        x = OperatorInputs(particle_pos=self._tensor(norm.positions(state.positions)),
                           particle_features=self._tensor(norm.field("displacement", state.displacement)),
                           grid=self._tensor(grid_input(norm, state.fluid_velocity, state.solid_fraction, flux)),
                           mixing_grid=self._tensor(mixing_input(norm, state.mixing)), scalars=self.scalars,
                           noise=noise)
        volume = torch.tensor([self.solid_volume], dtype=torch.float64, device=self.device)
        view = None if self.noise_std is None else perturb_inputs(
            x, self.noise_std, lambda _, t: torch.randn(t.shape, generator=self.generator, device=t.device,
                                                        dtype=t.dtype))
        nxt = advance(self.net, x, norm, n_particles=len(state.positions), generator=self.generator,
                      chunk_size=self.chunk_size, step_scales=self.step_scales, stability=self.stability,
                      volume=volume, net_view=view)
        grid = np.moveaxis(nxt.grid[0].double().cpu().numpy(), 0, -1)
        solid_fraction = norm.field_back("solid_fraction", grid[..., 3:4])
        if self.conserve_solid_volume:  # the step projected in float32: remove its round-off
            total = float(np.sum(solid_fraction))
            if np.isfinite(total) and total > 0:  # a broken field is left for the divergence check
                ratio = self.solid_volume / total
                if abs(ratio - 1.0) > ROUND_OFF:  # more than round-off: the rescale moves capped cells off the cap
                    log.warning("step to t=%.3f s: the projected solid volume is %.3g %% off the volume to keep; "
                                "rescaling moves cells at the packing cap by as much", state.time + self.dt,
                                100 * (1 / ratio - 1))
                solid_fraction = solid_fraction * ratio
        return FbState(
            time=state.time + self.dt,
            positions=norm.positions_back(nxt.particle_pos[0].double().cpu().numpy()),
            displacement=norm.field_back("displacement", nxt.particle_features[0].double().cpu().numpy()),
            fluid_velocity=norm.field_back("fluid_velocity", grid[..., :3]),
            solid_fraction=solid_fraction,
            mixing=norm.field_back("mixing", np.moveaxis(nxt.mixing_grid[0].double().cpu().numpy(), 0, -1)),
            solids_flux=norm.field_back("solids_flux", grid[..., 4:7]) if self.solids_flux else None,
        )


def perturbation_std(module: FluidizedBedModule, scale: float, device: str) -> dict[str, torch.Tensor] | None:
    """Per-channel std (model units) of `rollout_noise`: `scale` times the module's running one-step error
    (None when off)."""
    if not scale:
        return None
    std = {name: getattr(module, f"step_error_{name}", None) for name in ("particles", "fluid", "mixing")}
    if any(s is None for s in std.values()) or not any(float(s.abs().sum()) > 0 for s in std.values()):
        raise ConfigError(f"rollout_noise={scale:g} needs the model's running one-step error, which this checkpoint "
                          "does not hold (trained without the running one-step error, or as a residual model): "
                          "use rollout_noise=0")
    return {name: scale * s.detach().float().to(device) for name, s in std.items()}


class DataStepper:
    """Replays a stored trajectory as if it were predicted: ground truth fed through the rollout and
    evaluation path must come out unchanged (the test of that path)."""

    def __init__(self, f: FbFile):
        self.f = f
        self.dt = f.dt

    def step(self, state: FbState) -> FbState:
        k = round(state.time / self.dt) + 1
        if k >= self.f.n_snapshots:
            raise DataError(f"{self.f.path}: the stored trajectory ends at snapshot {self.f.n_snapshots - 1}")
        return initial_state(self.f, k)


@dataclass
class Rollout:
    """The states of a rollout, stacked (grid fields in float32, as stored); particle samples every
    `particles_every` steps."""

    times: np.ndarray
    fluid_velocity: np.ndarray
    solid_fraction: np.ndarray
    mixing: np.ndarray
    sample_times: np.ndarray
    positions: np.ndarray
    displacement: np.ndarray
    steps_requested: int
    diverged_at: int | None = None  # the step whose state failed the check
    divergence: str = ""
    attrs: dict[str, Any] = field(default_factory=dict)

    @property
    def steps_done(self) -> int:
        return len(self.times) - 1

    def message(self) -> str:
        if self.diverged_at is None:
            return f"rollout finished: {self.steps_done} steps ({self.times[-1] - self.times[0]:.2f} s), no divergence"
        return (f"rollout diverged at step {self.diverged_at} (t = {self.times[0] + self.diverged_at * self.dt:.3f} "
                f"s): {self.divergence}; kept the {self.steps_done + 1} states before it")

    @property
    def dt(self) -> float:
        return float(self.times[1] - self.times[0]) if len(self.times) > 1 else float(self.attrs.get("dt", 0.0))


def rollout(stepper: Stepper, state: FbState, steps: int, limits: DivergenceLimits | None = None,
            particles_every: int = 10, progress: bool = True) -> Rollout:
    """Step `steps` times from `state`, stopping at the first state that fails `limits`."""
    checks.positive_int("steps", steps)
    checks.positive_int("particles_every", particles_every)
    limits = limits or DivergenceLimits()
    grids, samples = [_grid_fields(state)], [state]  # particles are kept only every particles_every steps
    diverged_at, reason = None, ""
    bar = tqdm(range(1, steps + 1), desc="rollout", unit="step", disable=not progress, mininterval=1.0)
    for s in bar:
        state = stepper.step(state)
        problem = limits.problem(state)
        if problem is not None:
            diverged_at, reason = s, problem
            break
        grids.append(_grid_fields(state))
        if s % particles_every == 0:
            samples.append(state)
    bar.close()
    out = Rollout(
        times=np.array([g[0] for g in grids]),
        fluid_velocity=np.stack([g[1] for g in grids]),
        solid_fraction=np.stack([g[2] for g in grids]),
        mixing=np.stack([g[3] for g in grids]),
        sample_times=np.array([x.time for x in samples]),
        positions=np.stack([x.positions for x in samples]),
        displacement=np.stack([x.displacement for x in samples]),
        steps_requested=steps, diverged_at=diverged_at, divergence=reason, attrs={"dt": stepper.dt},
    )
    if diverged_at is not None:
        log.warning("%s", out.message())
    return out


def _grid_fields(s: FbState) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    return s.time, s.fluid_velocity.astype(np.float32), s.solid_fraction.astype(np.float32), s.mixing.astype(np.float32)


# ---- files
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
    """Validating reader of a rollout file; the grid fields read like `FbFile`'s."""

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
def load_fb_checkpoint(path: Path, device: str = "cpu") -> FluidizedBedModule:
    """A trained fluidized-bed model; a checkpoint of another kind is refused with a message."""
    return read_checkpoint(path).module("fluidized_bed", device, "a fluidized-bed rollout or evaluation")


def check_velocity(norm: FbNormalizer, velocity: float) -> bool:
    """True (and a warning stating the trained range) when `velocity` is outside what the model saw."""
    checks.positive("velocity", velocity)
    if norm.in_trained_range(velocity):
        return False
    msg = (f"inlet velocity {velocity:g} m/s is outside the range the model was trained on "
           f"[{norm.velocity_lo:g}, {norm.velocity_hi:g}] m/s: the rollout extrapolates (flagged in its outputs)")
    warnings.warn(msg, ExtrapolationWarning, stacklevel=2)
    log.warning("%s", msg)
    return True


def check_grid(norm: FbNormalizer, f: FbFile) -> None:
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
                progress: bool = True, conserve_solid_volume: bool | None = None,
                mixing: str | None = None, mirror_alternate: bool | None = None,
                rollout_noise: float | None = None, advection_correction: float | None = None) -> dict[str, Any]:
    """Load, roll out, write rollout.h5 (+ vtk/, rollout.json) into `out_dir`; return the summary."""
    checks.positive_int("steps", steps)
    limits = limits or DivergenceLimits()
    module = load_fb_checkpoint(ckpt, device)
    meta, norm = module.metadata, module.norm
    extrapolation = check_velocity(norm, velocity)
    path, source = initial_file(meta, Path(ckpt), velocity, datasets_dir, dataset_dir, init, init_sim)
    with FbFile(path) as f:
        check_grid(norm, f)
        state = initial_state(f, init_snapshot)
        present = np.isfinite(f.positions(init_snapshot)).all(axis=1)
        volumes = f.particle_volumes[present]
        grid = f.grid
    stepper = ModelStepper(module, velocity, seed, device, conserve_solid_volume, mixing,
                           advection_correction=advection_correction, mirror_alternate=mirror_alternate,
                           rollout_noise=rollout_noise)
    r = rollout(stepper, state, steps, limits, particles_every, progress)
    summary = {
        "checkpoint": str(Path(ckpt).resolve()), "data_name": meta["data_name"], "inlet_velocity": float(velocity),
        "extrapolation": extrapolation, "trained_velocity_range": [norm.velocity_lo, norm.velocity_hi],
        "initial_state": f"{source} snapshot {init_snapshot}", "seed": seed, "max_packing": limits.max_packing,
        "tolerance": limits.tolerance, "dt": norm.dt, "training_horizon_steps": norm.horizon_steps,
        "conserve_solid_volume": stepper.stability.conserve_volume, "mixing": stepper.stability.mixing,
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
    """`neuraldem evaluate rollout ckpt=... velocity=... steps=...` for a bed checkpoint (conf/rollout.yaml);
    False when the rollout diverged."""
    from neuraldem.eval.checkpoints import resolve_device
    from neuraldem.scenes.fluidized_bed.surrogate.options import MIXING_MODES, check_rollout_value

    checks.required(cfg, "rollout", {"ckpt": "ckpt=<run>/checkpoints/last.ckpt", "velocity": "velocity=1.6"})
    checks.one_of("device", cfg.device, ("auto", "cpu", "cuda"))
    limits = DivergenceLimits(checks.number("max_packing", cfg.max_packing, lo=0.0, hi=1.0, lo_open=True),
                              checks.number("tolerance", cfg.tolerance, lo=0.0, hi=0.5))
    summary = run_rollout(
        Path(cfg.ckpt), checks.positive("velocity", cfg.velocity), checks.positive_int("steps", cfg.steps),
        out_dir=Path(cfg.paths.output_dir), datasets_dir=Path(cfg.paths.datasets_dir),
        dataset_dir=cfg.dataset_dir, init=cfg.init, init_sim=cfg.init_sim, init_snapshot=cfg.init_snapshot,
        seed=checks.positive_int("seed", cfg.seed, allow_zero=True), limits=limits,
        particles_every=cfg.particles_every, vtk=bool(cfg.vtk), vtk_every=cfg.vtk_every,
        device=resolve_device(cfg.device), progress=bool(cfg.progress),
        conserve_solid_volume=None if cfg.conserve_solid_volume is None else checks.boolean(
            "conserve_solid_volume", cfg.conserve_solid_volume),
        mixing=None if cfg.get("mixing") is None else checks.one_of("mixing", cfg.mixing, MIXING_MODES),
        mirror_alternate=None if cfg.get("mirror_alternate") is None else checks.boolean(
            "mirror_alternate", cfg.mirror_alternate),
        rollout_noise=None if cfg.get("rollout_noise") is None else check_rollout_value(
            "rollout_noise", cfg.rollout_noise),
        advection_correction=None if cfg.get("advection_correction") is None else check_rollout_value(
            "advection_correction", cfg.advection_correction))
    print(summary["message"])
    if summary["extrapolation"]:
        lo, hi = summary["trained_velocity_range"]
        print(f"note: {cfg.velocity} m/s is outside the trained range [{lo:g}, {hi:g}] m/s (extrapolation)")
    print(f"results in {cfg.paths.output_dir}")
    return summary["diverged_at"] is None
