"""Autoregressive, field-based rollout of a fluidized-bed model, with divergence detection (its files and the
command that writes them: `rollout_run.py`).

Each step feeds the model its own previous prediction: the decoded fluid velocity, solid fraction and mixing
grids, and particles re-sampled from the predicted solid fraction with the decoded displacement field at
their positions (`neuraldem.scenes.fluidized_bed.surrogate.autoregressive`, the same step push-forward training takes).
Particles are never tracked. The first state is a snapshot of a stored trajectory (positions, last displacement,
fields).

Every new state is checked; NaN/inf anywhere, or a solid fraction below -tolerance or above max_packing +
tolerance, stops the rollout and names the step. The states before it are kept and written.

Rollout file (kind "fluidized_bed_rollout", `rollout_run.write_rollout`): the grid fields under the ground truth's
names, so the same metric code reads both:
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

import gc
import logging
import weakref
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import torch
from tqdm import tqdm

from neuraldem.config import checks
from neuraldem.errors import ConfigError, DataError
from neuraldem.models.multi_branch_operator import OperatorInputs
from neuraldem.models.operator_onnx import OnnxOperator, resolve_runtime
from neuraldem.paths import data_dir
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import advance, perturb_inputs
from neuraldem.scenes.fluidized_bed.surrogate.mirror import mirror_grid, mirror_points, mirror_vectors
from neuraldem.scenes.fluidized_bed.surrogate.normalization import BedNormalizer, grid_input, mixing_input
from neuraldem.scenes.fluidized_bed.surrogate.options import BedStability, RolloutOptions

if TYPE_CHECKING:  # a rollout needs no Lightning (`step_model`)
    from neuraldem.scenes.fluidized_bed.surrogate.module import BedModule
    from neuraldem.scenes.fluidized_bed.surrogate.step_model import BedStepModel

log = logging.getLogger(__name__)

ROLLOUT_KIND = "fluidized_bed_rollout"
DEFAULT_MAX_PACKING = 0.74  # densest packing of equal spheres; the kernel field of the data reaches ~0.72
DEFAULT_TOLERANCE = 0.05
ROUND_OFF = 1e-4  # relative volume error a float32 projection leaves


class ExtrapolationWarning(UserWarning):
    """The model is asked about an inlet velocity outside the range it was trained on."""


@dataclass
class BedState:
    """The model's input at one time, in physical units."""

    time: float
    positions: np.ndarray  # (N, 3) [m] particle input positions (data or sampled)
    displacement: np.ndarray  # (N, 3) [m] displacement that brought them there
    fluid_velocity: np.ndarray  # (nx, ny, nz, 3) [m/s]
    solid_fraction: np.ndarray  # (nx, ny, nz)
    mixing: np.ndarray  # (nx, ny, nz)
    solids_flux: np.ndarray | None = None  # (nx, ny, nz, 3) [m/s] of the last step (models trained with it)
    # the particles whose displacement was decoded (None: all); the others hold the mean displacement, which
    # only the stepper that made the state may feed on (its next step reads none of them)
    decoded: np.ndarray | None = None


DEFAULT_INIT_SNAPSHOT = 1  # snapshot 0 has no last displacement (zero), which training almost never sees


def initial_state(f: BedFile, snapshot: int = DEFAULT_INIT_SNAPSHOT, key: str = "init_snapshot") -> BedState:
    """Snapshot `snapshot` of a stored trajectory as a rollout's first state (absent particles dropped)."""
    if isinstance(snapshot, bool) or not isinstance(snapshot, int) or not 0 <= snapshot < f.n_snapshots:
        raise ConfigError(f"config value {key}={snapshot!r} is invalid: {f.path} has snapshots 0 .. "
                          f"{f.n_snapshots - 1} (override it, e.g. {key}={DEFAULT_INIT_SNAPSHOT})")
    pos = f.positions(snapshot)
    disp = f.displacement(snapshot - 1) if snapshot > 0 else np.zeros_like(pos)
    ok = np.isfinite(pos).all(axis=1) & np.isfinite(disp).all(axis=1)
    return BedState(time=float(f.times[snapshot]), positions=pos[ok], displacement=disp[ok],
                   fluid_velocity=f.fluid_velocity(snapshot), solid_fraction=f.solid_fraction(snapshot),
                   mixing=f.mixing(snapshot), solids_flux=f.solids_flux(snapshot))


def mirror_state(s: BedState, lo_x: float, hi_x: float) -> BedState:
    """The state of the bed mirrored at its mid-plane in x (an involution: applied twice, the state itself)."""
    return BedState(time=s.time, positions=mirror_points(s.positions, lo_x, hi_x),
                   displacement=mirror_vectors(s.displacement),
                   fluid_velocity=mirror_grid(s.fluid_velocity, vector=True),
                   solid_fraction=mirror_grid(s.solid_fraction, vector=False),
                   mixing=mirror_grid(s.mixing, vector=False),
                   solids_flux=None if s.solids_flux is None else mirror_grid(s.solids_flux, vector=True),
                   decoded=s.decoded)


@dataclass
class DivergenceLimits:
    max_packing: float = DEFAULT_MAX_PACKING
    tolerance: float = DEFAULT_TOLERANCE

    def __post_init__(self) -> None:
        checks.number("max_packing", self.max_packing, lo=0.0, hi=1.0, lo_open=True)
        checks.number("tolerance", self.tolerance, lo=0.0, hi=0.5)

    def problem(self, s: BedState) -> str | None:
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
    """What `rollout` steps. A stepper with `decodes_on_demand = True` also takes `step(state,
    all_particles=False)`: a state whose particles are only partly decoded (`BedState.decoded`), for the steps
    whose particles nobody keeps."""

    dt: float

    def step(self, state: BedState) -> BedState: ...


_ONNX_NETS: weakref.WeakKeyDictionary[torch.nn.Module, dict[tuple[Any, ...], OnnxOperator]] = \
    weakref.WeakKeyDictionary()


class ModelStepper:
    """A trained bed model (its `BedModule`, or the `BedStepModel` read without it) as a stepper, conditioned
    on one inlet velocity.

    The step applies the checkpoint's stability options (`neuraldem.scenes.fluidized_bed.surrogate.options`), the
    rollout options given in `options` in their place (`RolloutOptions`; None = the checkpoint's): with volume
    conservation (`conserve_volume`) the predicted solid fraction is clamped >= 0 and scaled to the solid volume of
    the first state it was given (the bed is closed: CFD-DEM loses no particle), so the rollout holds it to
    round-off. A model trained without it and rolled
    out with it is a projection on top of the model: its drift is then 0 by construction and says nothing of
    the model's own conservation. A stochastic model draws its latent noise from this stepper's generator.
    With `mirror_alternate` every second step is taken in the mirror image of the bed, with `rollout_noise` the
    net reads a perturbed copy of each state (`BedStability`; both drawn from this stepper's generator).
    `runtime`: torch, onnx (the net's calls in ONNX Runtime, equal to round-off, not bit for bit: the shipped
    model's what-if 1.63x faster, its answers the same well within the seed spread,
    results/fluidized_bed/speed/fb_runtime.md) or auto (onnx where installed). On the ONNX path
    (`decodes_on_demand`) a step whose particles nobody keeps (`rollout`'s steps between samples) decodes the
    displacement only where the next step's encoder reads it (`autoregressive.next_inputs`) and hands that step
    its particle graph."""

    def __init__(self, module: BedModule | BedStepModel, velocity: float, seed: int = 0, device: str = "cpu",
                 options: RolloutOptions | None = None, runtime: str = "torch"):
        base = getattr(module, "stability", None) or BedStability()
        self.stability = (options or RolloutOptions()).apply(base)
        self.noise_std = perturbation_std(module, self.stability.rollout_noise, device)
        self.steps_taken = 0
        if self.stability.mixing == "advect" and not module.metadata.get("solids_flux", False):
            raise ConfigError("config value rollout.mixing=advect needs a model trained with the solids flux "
                              "(data.datamodule.solids_flux=true): use rollout.mixing=absolute for this checkpoint")
        self.conserve_volume = self.stability.conserve_volume
        self.solid_volume: float | None = None  # sum of the first state's solid fraction (cells are equal)
        self.net = module.net.to(device).eval()
        self.step_scales = getattr(module, "step_scales", None)  # a residual model's
        self.norm: BedNormalizer = module.norm
        self.solids_flux = bool(module.metadata.get("solids_flux", False))
        self.dt = self.norm.dt
        self.chunk_size = module.chunk_size
        self.device = device
        self.scalars = torch.tensor([[self.norm.velocity(velocity)]], dtype=torch.float32, device=device)
        self.generator = torch.Generator(device=device).manual_seed(int(seed))
        self.runtime = "torch"
        if runtime == "auto" and device != "cpu":
            runtime = "torch"
        if resolve_runtime(runtime) == "onnx":  # the same step in ONNX Runtime, equal to round-off
            self._use_onnx(runtime, device)
        # on-demand particle decoding equals decoding all to round-off only: torch steps stay bit for bit the
        # reference (evaluation, training's rollout validation, the stored results); the ONNX path, itself equal to
        # torch to round-off, decodes on demand
        self.decodes_on_demand = self.runtime == "onnx"
        self._next_graph: tuple[torch.Tensor, Any, np.ndarray] | None = None  # the next input's positions,
        # their particle graph and the particles it reads

    def _use_onnx(self, runtime: str, device: str) -> None:
        """The net's calls in ONNX Runtime (`models.operator_onnx`: exported once per model into the data
        dir's cache); with runtime=auto a failed export leaves the step in torch, with a warning."""
        if device != "cpu":
            raise ConfigError(f"runtime=onnx runs on the CPU, not on {device}", "use runtime=torch there")
        key = (self.stability.mixing != "advect", torch.get_num_threads(), tuple(int(n) for n in self.norm.grid_shape))
        opened = _ONNX_NETS.setdefault(self.net, {})
        try:
            if key not in opened:  # one export check and session per net and setting, not per rollout
                net = OnnxOperator(self.net, data_dir() / "cache" / "onnx", off_branches=key[0], threads=key[1])
                net.prepare(key[2])
                opened[key] = net
        except (OSError, DataError) as err:
            if runtime == "onnx":
                raise
            log.warning("the rollout steps in torch: the ONNX export failed (%s)", err)
            return
        self.net, self.runtime = opened[key], "onnx"

    def _tensor(self, x: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))[None].to(self.device)

    def step(self, state: BedState, all_particles: bool = True) -> BedState:
        mirrored = self._mirrored(self.steps_taken)
        self.steps_taken += 1
        if not mirrored:
            return self._step(state, False, all_particles)
        lo_x, hi_x = self.norm.box_lo[0], self.norm.box_hi[0]
        return mirror_state(self._step(mirror_state(state, lo_x, hi_x), True, all_particles), lo_x, hi_x)

    def _mirrored(self, step: int) -> bool:
        return self.stability.mirror_alternate and step % 2 == 1

    def _input_positions(self, positions: np.ndarray) -> torch.Tensor:
        return self._tensor(self.norm.positions(positions))

    def _output_positions(self, positions: torch.Tensor) -> np.ndarray:
        return self.norm.positions_back(positions[0].double().cpu().numpy())

    def _rows_next_step_reads(self, mirrored: bool) -> Callable[[torch.Tensor], torch.Tensor]:
        """For the particles this step samples (model units, this step's frame): the particles the next step's
        encoder reads. Their positions go the way the next step's input takes (to physical units, out of and
        into the mirror frame), so the graph found here is the one the next step would find; it is kept for it."""
        encoder = self.net.encoders["particles"]
        lo_x, hi_x = self.norm.box_lo[0], self.norm.box_hi[0]

        def rows(positions: torch.Tensor) -> torch.Tensor:
            out = self._output_positions(positions)
            if mirrored:
                out = mirror_points(out, lo_x, hi_x)
            if self._mirrored(self.steps_taken):
                out = mirror_points(out, lo_x, hi_x)
            nxt = self._input_positions(out)
            graph = encoder.graph(nxt)
            read = graph.particles_read()
            self._next_graph = (nxt, graph, read.cpu().numpy())
            return read

        return rows

    def net_inputs(self, state: BedState, positions: torch.Tensor | None = None, graph: Any = None,
                   noise: torch.Tensor | None = None) -> OperatorInputs:
        """What the net reads of `state` at this stepper's velocity, in model units (a batch of one); `positions`:
        the state's positions already in model units, `graph`: their particle graph, when the caller has them."""
        norm = self.norm
        flux = state.solids_flux if self.solids_flux else None
        return OperatorInputs(
            particle_pos=self._input_positions(state.positions) if positions is None else positions,
            particle_graph=graph, particle_features=self._tensor(norm.field("displacement", state.displacement)),
            grid=self._tensor(grid_input(norm, state.fluid_velocity, state.solid_fraction, flux)),
            mixing_grid=self._tensor(mixing_input(norm, state.mixing)), scalars=self.scalars, noise=noise)

    # inference_mode, not just no_grad: no version counters or view tracking (bench fb_speed on the shipped net:
    # 0.832 -> 0.791 s per simulated second at one thread, fields bit-identical)
    @torch.inference_mode()
    def _step(self, state: BedState, mirrored: bool = False, all_particles: bool = True) -> BedState:
        norm = self.norm
        if self.solid_volume is None:
            self.solid_volume = float(np.sum(state.solid_fraction))
        if self.solids_flux and state.solids_flux is None:
            raise DataError("this model reads the solids flux: start the rollout from a dataset trajectory "
                            "(initial_state computes it)")
        positions = self._input_positions(state.positions)
        graph = None
        if self._next_graph is not None and torch.equal(self._next_graph[0], positions):
            graph = self._next_graph[1]
        elif state.decoded is not None:
            raise ValueError("a state with partly decoded particles (all_particles=False) can only be stepped by "
                             "the stepper that made it, right after")
        self._next_graph = None
        noise = None
        if self.net.noise_dim:
            noise = torch.randn(1, self.net.noise_dim, generator=self.generator, device=self.device)
        x = self.net_inputs(state, positions, graph, noise)
        volume = torch.tensor([self.solid_volume], dtype=torch.float64, device=self.device)
        reads_particles = self.net.particle_branch and not all_particles
        rows = self._rows_next_step_reads(mirrored) if reads_particles else None
        view = None if self.noise_std is None else perturb_inputs(
            x, self.noise_std, lambda _, t: torch.randn(t.shape, generator=self.generator, device=t.device,
                                                        dtype=t.dtype))
        nxt = advance(self.net, x, norm, n_particles=len(state.positions), generator=self.generator,
                      chunk_size=self.chunk_size, step_scales=self.step_scales, stability=self.stability,
                      volume=volume, net_view=view, rows=rows)
        grid = np.moveaxis(nxt.grid[0].double().cpu().numpy(), 0, -1)
        solid_fraction = norm.field_back("solid_fraction", grid[..., 3:4])
        if self.conserve_volume:  # the step projected in float32: remove its round-off
            total = float(np.sum(solid_fraction))
            if np.isfinite(total) and total > 0:  # a broken field is left for the divergence check
                ratio = self.solid_volume / total
                if abs(ratio - 1.0) > ROUND_OFF:  # more than round-off: the rescale moves capped cells off the cap
                    log.warning("step to t=%.3f s: the projected solid volume is %.3g %% off the volume to keep; "
                                "rescaling moves cells at the packing cap by as much", state.time + self.dt,
                                100 * (1 / ratio - 1))
                solid_fraction = solid_fraction * ratio
        return BedState(
            time=state.time + self.dt,
            positions=self._output_positions(nxt.particle_pos),
            displacement=norm.field_back("displacement", nxt.particle_features[0].double().cpu().numpy()),
            fluid_velocity=norm.field_back("fluid_velocity", grid[..., :3]),
            solid_fraction=solid_fraction,
            mixing=norm.field_back("mixing", np.moveaxis(nxt.mixing_grid[0].double().cpu().numpy(), 0, -1)),
            solids_flux=norm.field_back("solids_flux", grid[..., 4:7]) if self.solids_flux else None,
            decoded=None if self._next_graph is None else self._next_graph[2],
        )


def perturbation_std(module: BedModule | BedStepModel, scale: float, device: str) -> dict[str, torch.Tensor] | None:
    """Per-channel std (model units) of `rollout_noise`: `scale` times the module's running one-step error
    (None when off)."""
    if not scale:
        return None
    std = {name: getattr(module, f"step_error_{name}", None) for name in ("particles", "fluid", "mixing")}
    if any(s is None for s in std.values()) or not any(float(s.abs().sum()) > 0 for s in std.values()):
        raise ConfigError(f"rollout.rollout_noise={scale:g} needs the model's running one-step error, which this "
                          "checkpoint does not hold (trained without the running one-step error, or as a residual "
                          "model): use rollout.rollout_noise=0")
    return {name: scale * s.detach().float().to(device) for name, s in std.items()}


class DataStepper:
    """Replays a stored trajectory as if it were predicted: ground truth fed through the rollout and
    evaluation path must come out unchanged (the test of that path)."""

    def __init__(self, f: BedFile):
        self.f = f
        self.dt = f.dt

    def step(self, state: BedState) -> BedState:
        k = round(state.time / self.dt) + 1
        if k >= self.f.n_snapshots:
            raise DataError(f"{self.f.path}: the stored trajectory ends at snapshot {self.f.n_snapshots - 1}")
        return initial_state(self.f, k)


class GatedStepper:
    """A stepper that calls `gate()` before each step (which may wait, or raise: the explorer's `Superseded`). The
    steps are the wrapped stepper's own, in the same order: pauses do not change the rollout."""

    def __init__(self, stepper: Stepper, gate: Callable[[], None]):
        self.stepper, self.gate, self.dt = stepper, gate, stepper.dt
        self.decodes_on_demand = getattr(stepper, "decodes_on_demand", False)

    def step(self, state: BedState, **kwargs: Any) -> BedState:
        self.gate()
        return self.stepper.step(state, **kwargs)


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


def rollout(stepper: Stepper, state: BedState, steps: int, limits: DivergenceLimits | None = None,
            particles_every: int = 10, progress: bool = True) -> Rollout:
    """Step `steps` times from `state`, stopping at the first state that fails `limits`."""
    checks.positive_int("steps", steps)
    checks.positive_int("particles_every", particles_every)
    limits = limits or DivergenceLimits()
    on_demand = getattr(stepper, "decodes_on_demand", False)
    grids, samples = [_grid_fields(state)], [state]  # particles are kept only every particles_every steps
    diverged_at, reason = None, ""
    bar = tqdm(range(1, steps + 1), desc="rollout", unit="step", disable=not progress, mininterval=1.0)
    with _older_objects_left_alone():
        for s in bar:
            state = stepper.step(state, all_particles=s % particles_every == 0) if on_demand else stepper.step(state)
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


@contextmanager
def _older_objects_left_alone() -> Iterator[None]:
    """The objects alive before the loop are left out of the garbage collector's passes during it. With torch and
    Lightning imported they are hundreds of thousands, which every full pass walked while a rollout made its many
    small arrays: a noticeable share of a bed rollout's time (it is in the step times of
    results/fluidized_bed/speed/fb_speed.md)."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def _grid_fields(s: BedState) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    return s.time, s.fluid_velocity.astype(np.float32), s.solid_fraction.astype(np.float32), s.mixing.astype(np.float32)


# ---- files
