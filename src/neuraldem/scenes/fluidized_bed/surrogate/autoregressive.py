"""One field-based autoregressive step of the fluidized-bed model, in model units.

Shared by push-forward training and by rollouts, so both feed the model exactly the same kind of input:
the grid fields come from the decoded fluid and mixing branches; particles are never tracked: their input
positions are sampled anew from the predicted solid fraction (density proportional to it, uniform inside a
cell), and their input displacement is the particle branch decoded at those positions. A residual model
(`model.residual=true`) predicts the grid fields' change over the step, scaled per channel by the training
data's typical one-step change (`BedNormalizer.step_scale`); the next state is the input plus that change.

The stability options (`neuraldem.scenes.fluidized_bed.surrogate.options`) act inside this step, so training and
rollouts see
the same thing: the solid fraction projected onto the input's solid volume (`conserve_volume`) and the mixing
concentration carried by the predicted solids flux (`mixing=advect`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import lru_cache

import numpy as np
import torch

from neuraldem.models.modules import compiled
from neuraldem.models.modules.conservative_advection import advect_tagged, face_fluxes, net_outflow
from neuraldem.models.modules.patch_embedding import cell_centres
from neuraldem.models.multi_branch_operator import MultiBranchOperator, OperatorInputs
from neuraldem.scenes.fluidized_bed.surrogate.normalization import BedNormalizer
from neuraldem.scenes.fluidized_bed.surrogate.options import BedStability

SOLID_FRACTION_CHANNEL = 3  # fluid branch channels: fluid velocity (3), solid fraction (1)[, solids flux (3)]
FLUX_CHANNELS = slice(4, 7)


def _stats(norm: BedNormalizer, name: str, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The field's mean and std as tensors like `like` (shared, read-only: made once per values, dtype and device,
    not at every call of a rollout step)."""
    return _stat_tensors(tuple(norm.mean[name]), tuple(norm.std[name]), like.dtype, like.device)


@lru_cache(maxsize=64)
@torch.inference_mode(False)  # plain tensors even when first asked for in a rollout step: training reuses them
def _stat_tensors(mean: tuple[float, ...], std: tuple[float, ...], dtype: torch.dtype,
                  device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    return torch.tensor(mean, dtype=dtype, device=device), torch.tensor(std, dtype=dtype, device=device)


def water_fill(alpha: torch.Tensor, volume: torch.Tensor, cap: float) -> torch.Tensor:
    """min(s alpha, cap) per row of alpha (B, N) >= 0, with the one s >= 0 per row that makes the row sum
    `volume` (B, 1): the field scaled as a whole, the cells it pushes past the cap held there. Exact (sorted:
    with the k largest cells capped, s = (volume - k cap) / (sum of the others); the answer is the smallest k
    whose largest free cell stays under the cap). Cells over the cap before scaling are not held by themselves:
    a prediction that piles more than the volume into them is scaled down as a whole. A row with no solid
    outside its capped cells spreads the rest evenly over the empty ones; a volume past n * cap fills every
    cell to the cap. Differentiable through s; without a gradient to keep, on the CPU, computed by
    `_water_fill_numpy` (the same values, bit for bit)."""
    if alpha.device.type == "cpu" and not (torch.is_grad_enabled() and alpha.requires_grad):
        filled = _water_fill_numpy(alpha.detach().double().numpy(), volume.detach().double().reshape(-1, 1).numpy(),
                                   cap)
        if filled is not None:
            return torch.from_numpy(filled).to(alpha.dtype)
    b, n = alpha.shape
    work = alpha.double()
    target = volume.double().reshape(b, 1)
    srt = work.sort(dim=1, descending=True).values
    zero = srt.new_zeros(b, 1)
    taken = torch.cat([zero, srt.cumsum(dim=1)], dim=1)  # (B, n + 1): sum of the k largest
    tail = taken[:, -1:] - taken  # sum of the others
    k = torch.arange(n + 1, dtype=work.dtype, device=work.device)
    rest = target - cap * k
    scale = rest / tail.clamp(min=1e-300)
    largest_free = torch.cat([srt, zero], dim=1)
    ok = (rest >= 0) & (tail > 1e-12 * taken[:, -1:].clamp(min=1e-300)) & (scale * largest_free <= cap)
    found = ok.any(dim=1, keepdim=True)
    first = ok.to(torch.int8).argmax(dim=1, keepdim=True)  # the smallest such k
    s = scale.gather(1, first)
    filled = torch.minimum(s.clamp(min=0.0) * work, torch.full_like(work, cap))
    # no k works: every cell holding solid is at the cap; the rest goes evenly to the empty ones
    held = (work > 0).sum(dim=1, keepdim=True)
    even = ((target - cap * held) / (n - held).clamp(min=1)).clamp(0.0, cap)
    fallback = torch.where(work > 0, torch.full_like(work, cap), even.expand_as(work))
    return torch.where(found, filled, fallback).to(alpha.dtype)


def _water_fill_numpy(work: np.ndarray, target: np.ndarray, cap: float) -> np.ndarray | None:
    """`water_fill` in NumPy, the same operations in the same order (float64), for a rollout step: a few hundred
    cells, where each torch call costs several NumPy ones. None when a row needs the fallback (every solid cell
    at the cap; rare), which is left to the torch code."""
    if compiled.available():  # the same operations compiled (`neuraldem.models.modules.compiled`)
        filled, ok = compiled.kernels().water_fill_rows(np.ascontiguousarray(work), np.ascontiguousarray(target),
                                                        float(cap))
        return filled if ok else None
    b, n = work.shape
    srt = np.sort(work, axis=1)[:, ::-1]
    taken = np.zeros((b, n + 1))
    np.cumsum(srt, axis=1, out=taken[:, 1:])
    tail = taken[:, -1:] - taken
    rest = target - cap * np.arange(n + 1, dtype=np.float64)
    scale = rest / np.maximum(tail, 1e-300)
    largest_free = np.concatenate([srt, np.zeros((b, 1))], axis=1)
    ok = (rest >= 0) & (tail > 1e-12 * np.maximum(taken[:, -1:], 1e-300)) & (scale * largest_free <= cap)
    if not ok.any(axis=1).all():
        return None
    s = np.take_along_axis(scale, ok.argmax(axis=1)[:, None], axis=1)
    return np.minimum(np.maximum(s, 0.0) * work, cap)


def project_volume(fluid: torch.Tensor, norm: BedNormalizer, volume: torch.Tensor) -> torch.Tensor:
    """fluid (B, cells, C) model units with its solid fraction projected onto the physical set: 0 <= alpha <=
    the densest value of the training data (`norm.solid_fraction_max`; 0.74 if unknown) and sum over the cells =
    `volume` (B,) (the input state's: the bed is closed). Clamped at 0, then `water_fill`. Differentiable, so
    the loss of a model trained with it sees the projected field."""
    mean, std = _stats(norm, "solid_fraction", fluid)
    cap = float(norm.solid_fraction_max) if norm.solid_fraction_max > 0 else 0.74
    alpha = (fluid[..., SOLID_FRACTION_CHANNEL] * std[0] + mean[0]).clamp(min=0.0)
    alpha = water_fill(alpha, volume, cap)
    out = fluid.clone()
    out[..., SOLID_FRACTION_CHANNEL] = (alpha - mean[0]) / std[0]
    return out


def solid_volume(grid: torch.Tensor, norm: BedNormalizer) -> torch.Tensor:
    """(B,) sum over the cells of the solid fraction of a fluid-branch input grid (B, C, nx, ny, nz)."""
    mean, std = _stats(norm, "solid_fraction", grid)
    return (grid[:, SOLID_FRACTION_CHANNEL] * std[0] + mean[0]).flatten(1).sum(1)


@torch.no_grad()
def advect_mixing(inputs: OperatorInputs, fluid: torch.Tensor, norm: BedNormalizer,
                  scheme: str = "fct", correction: float = 1.0, consistent: bool = False) -> torch.Tensor:
    """Next mixing grid (B, cells, 1), model units: the input concentration carried over one step by the
    predicted solids flux (channels 4-6 of `fluid` (B, cells, 7)), starting from the input solid fraction;
    `consistent`: the flux corrected to carry the solid to the next solid fraction of `fluid` (channel 3).
    No gradient flows through it: the loss never scores the advected field (the off-branch is trained on its
    own prediction), only the next step reads it."""
    shape = tuple(inputs.grid.shape[2:])
    batch = fluid.shape[0]
    a_mean, a_std = _stats(norm, "solid_fraction", inputs.grid)
    alpha = inputs.grid[:, SOLID_FRACTION_CHANNEL] * a_std[0] + a_mean[0]
    m_mean, m_std = _stats(norm, "mixing", inputs.grid)
    conc = inputs.mixing_grid[:, 0] * m_std[0] + m_mean[0]
    f_mean, f_std = _stats(norm, "solids_flux", fluid)
    flux = (fluid[..., FLUX_CHANNELS] * f_std + f_mean).transpose(1, 2).reshape(batch, 3, *shape)
    spacing = [(hi - lo) / n for lo, hi, n in zip(norm.box_lo, norm.box_hi, norm.grid_shape, strict=True)]
    target = None
    if consistent:
        target = (fluid[..., SOLID_FRACTION_CHANNEL] * a_std[0] + a_mean[0]).reshape(batch, *shape)
    new_conc, _ = advect_tagged(alpha, conc, flux, norm.dt, spacing, scheme=scheme, correction=correction,
                                target=target)
    return ((new_conc - m_mean[0]) / m_std[0]).reshape(batch, -1, 1)


def continuity_residual(inputs: OperatorInputs, fluid: torch.Tensor, norm: BedNormalizer) -> torch.Tensor:
    """(B, cells) how far the step's solids flux (channels 4-6 of `fluid` (B, cells, 7), model units) is from
    carrying the input solid fraction to the step's next one (channel 3): alpha_in - alpha_next - the flux's net
    outflow over dt, on the face fluxes `advect_mixing` moves the tagged solid with, in units of the training
    data's RMS one-step change of the solid fraction, the row mean removed (no flux can carry a change of the
    total). Zero for a flux that needs no correction under advection_flux=consistent. The gradient reaches only
    the flux: the solid fractions are held as given (the loss teaches the flux to carry the predicted solid; the
    solid fraction is taught by the data alone, as before)."""
    shape = tuple(inputs.grid.shape[2:])
    batch = fluid.shape[0]
    a_mean, a_std = _stats(norm, "solid_fraction", fluid)
    alpha_in = (inputs.grid[:, SOLID_FRACTION_CHANNEL] * a_std[0] + a_mean[0]).detach()
    alpha_next = (fluid[..., SOLID_FRACTION_CHANNEL] * a_std[0] + a_mean[0]).reshape(batch, *shape).detach()
    f_mean, f_std = _stats(norm, "solids_flux", fluid)
    flux = (fluid[..., FLUX_CHANNELS] * f_std + f_mean).transpose(1, 2).reshape(batch, 3, *shape)
    spacing = [(hi - lo) / n for lo, hi, n in zip(norm.box_lo, norm.box_hi, norm.grid_shape, strict=True)]
    outflow = net_outflow(face_fluxes(flux), norm.dt, spacing, alpha_in)
    r = (alpha_in - alpha_next - outflow).reshape(batch, -1)
    r = r - r.mean(dim=1, keepdim=True)
    return r / float(np.asarray(norm.step_rms["solid_fraction"]).reshape(-1)[0])


def grid_queries(inputs: OperatorInputs) -> torch.Tensor:
    """(B, cells, 3) normalised cell centres of the fluid grid, in the C order of the decoded fields."""
    centres = cell_centres(inputs.grid.shape[2:], device=inputs.grid.device)
    return centres.expand(inputs.grid.shape[0], -1, -1)


def sample_positions(solid_fraction: torch.Tensor, n: int,
                     generator: torch.Generator | Sequence[torch.Generator] | None = None) -> torch.Tensor:
    """(B, n, 3) normalised positions drawn with density proportional to the solid fraction (B, nx, ny, nz).

    Negative and non-finite values count as empty; a field with no solid anywhere is sampled uniformly
    (a diverging rollout is caught by its caller, not here). `generator`: one for the batch, or one per row
    (a row's positions then depend on nothing else: the training draws of `neuraldem.lit.distributed`)."""
    if isinstance(generator, Sequence):
        if len(generator) != solid_fraction.shape[0]:
            raise ValueError(f"{len(generator)} generators for {solid_fraction.shape[0]} rows")
        return torch.cat([sample_positions(solid_fraction[i:i + 1], n, g) for i, g in enumerate(generator)])
    batch, shape = solid_fraction.shape[0], solid_fraction.shape[1:]
    weights = torch.nan_to_num(solid_fraction.reshape(batch, -1).float(), nan=0.0, posinf=0.0).clamp(min=0.0)
    weights = torch.where(weights.sum(dim=1, keepdim=True) > 0, weights, torch.ones_like(weights))
    device = generator.device if generator is not None else solid_fraction.device
    cell = torch.multinomial(weights.to(device), n, replacement=True, generator=generator)
    dims = torch.tensor(shape, device=device)
    ijk = _unravel(cell, tuple(int(d) for d in shape))
    offset = torch.rand(batch, n, 3, generator=generator, device=device)
    return ((ijk + offset) / dims).to(solid_fraction.device)


def _unravel(cell: torch.Tensor, shape: tuple[int, ...]) -> torch.Tensor:
    """(..., ndim) C-order indices of flat cell indices: torch.unravel_index's integers, in a few operations
    instead of its many small ones (a rollout samples every step)."""
    out, rest = [], cell
    for n in reversed(shape):
        out.append(rest % n)
        rest = rest // n
    return torch.stack(out[::-1], dim=-1)


def grid_cells(grid: torch.Tensor) -> torch.Tensor:
    """(B, C, nx, ny, nz) -> (B, cells, C), cells in the C order of `grid_queries` (and of the targets)."""
    return grid.flatten(2).transpose(1, 2)


def grid_step_scales(norm: BedNormalizer) -> dict[str, torch.Tensor]:
    """Per-channel scale of one step's change, model units, for the fluid (fluid velocity + solid fraction) and
    mixing branches: a residual model's output times this is the change of the field over one step."""
    fluid = np.concatenate([norm.step_scale("fluid_velocity"), norm.step_scale("solid_fraction")])
    return {"fluid": torch.tensor(fluid, dtype=torch.float32),
            "mixing": torch.tensor(norm.step_scale("mixing"), dtype=torch.float32)}


def next_grid_fields(out: dict[str, torch.Tensor], inputs: OperatorInputs,
                     step_scales: dict[str, torch.Tensor] | None) -> dict[str, torch.Tensor]:
    """The decoded grid branches (B, cells, C) as next states, model units: the output itself, or for a
    residual model (`step_scales` given) the input plus the output times the step scale."""
    grids = {"fluid": inputs.grid, "mixing": inputs.mixing_grid}
    if step_scales is None:
        return {name: out[name] for name in grids if name in out}
    return {name: grid_cells(grid) + out[name] * step_scales[name].to(out[name].device)
            for name, grid in grids.items() if name in out}


def decode_grid(net: MultiBranchOperator, tokens: dict[str, torch.Tensor], cond: torch.Tensor,
                inputs: OperatorInputs, chunk_size: int | None = None,
                step_scales: dict[str, torch.Tensor] | None = None, mixing: bool = True) -> dict[str, torch.Tensor]:
    """Next fluid (B, cells, C) and mixing (B, cells, 1) states, model units, before the stability options.
    mixing=False leaves the mixing decoder out and passes the input's mixing grid on: for a step whose
    stability options replace it (mixing=advect), where decoding it only cost time (a third of the decoding)."""
    queries = grid_queries(inputs)
    branches = ("fluid", "mixing") if mixing else ("fluid",)
    out = next_grid_fields(net.decode(tokens, cond, {b: queries for b in branches}, chunk_size=chunk_size),
                           inputs, step_scales)
    if not mixing:
        out["mixing"] = grid_cells(inputs.mixing_grid)
    return out


def apply_stability(fields: dict[str, torch.Tensor], inputs: OperatorInputs, norm: BedNormalizer,
                    stability: BedStability | None, volume: torch.Tensor | None) -> dict[str, torch.Tensor]:
    """The decoded next state with the step's stability options applied (volume projection, mixing advection)."""
    if stability is None:
        return fields
    out = dict(fields)
    if stability.conserve_volume:
        out["fluid"] = project_volume(out["fluid"], norm, solid_volume(inputs.grid, norm) if volume is None else volume)
    if stability.mixing == "advect":
        out["mixing"] = advect_mixing(inputs, out["fluid"], norm, stability.advection_scheme,
                                      stability.advection_correction, stability.advection_flux == "consistent")
    return out


def next_inputs(net: MultiBranchOperator, tokens: dict[str, torch.Tensor], cond: torch.Tensor,
                fields: dict[str, torch.Tensor], inputs: OperatorInputs, norm: BedNormalizer, n_particles: int,
                generator: torch.Generator | Sequence[torch.Generator] | None = None,
                chunk_size: int | None = None,
                rows: Callable[[torch.Tensor], torch.Tensor | None] | None = None) -> OperatorInputs:
    """The next state as the next input: the grids, particles re-sampled from the solid fraction with the
    particle branch decoded at them (zero displacement for a grid-only model).

    `rows(positions)` (a batch of one): the indices of the particles whose displacement is needed, None for
    all; the others get 0 (model units). A rollout step in ONNX Runtime asks only for the particles the next
    step's encoder reads (a quarter of them on the shipped model), and for all of them when they are kept. Queries never
    interact, so a subset decodes to those rows of decoding all, up to the last bit: the matrix kernels may round
    a row differently for another number of rows (on the shipped model, a 300-step rollout's fields came to differ
    from decoding all in their last bits late in the rollout)."""
    shape = inputs.grid.shape[2:]
    batch = inputs.grid.shape[0]
    fluid = fields["fluid"].transpose(1, 2).reshape(batch, -1, *shape)
    mixing = fields["mixing"].transpose(1, 2).reshape(batch, -1, *shape)
    alpha = fluid[:, SOLID_FRACTION_CHANNEL] * norm.std["solid_fraction"][0] + norm.mean["solid_fraction"][0]
    positions = sample_positions(alpha, n_particles, generator)
    channels = inputs.particle_features.shape[-1]
    if not net.particle_branch:  # a grid-only model reads no particles: the samples only show where the solid is
        displacement = inputs.particle_features.new_zeros(positions.shape[0], n_particles, channels)
    else:
        wanted = None if rows is None or batch != 1 else rows(positions)
        if wanted is None or len(wanted) >= MIN_SUBSET_SHARE * n_particles or len(wanted) < MIN_SUBSET:
            displacement = net.decode(tokens, cond, {"particles": positions}, chunk_size=chunk_size)["particles"]
        else:
            decoded = net.decode(tokens, cond, {"particles": positions[:, wanted]}, chunk_size=chunk_size)
            displacement = positions.new_zeros(1, n_particles, channels)
            displacement[:, wanted] = decoded["particles"]
    return replace(inputs, particle_pos=positions, particle_features=displacement, grid=fluid, mixing_grid=mixing,
                   query_pos={}, supernode_idx=None, particle_graph=None, noise=None)


# a subset decode pays off below this share of the particles; under MIN_SUBSET rows all are decoded (a product of
# a few rows takes another kernel: a one-row decode differed from its row of the full one in the last bit)
MIN_SUBSET_SHARE = 0.75
MIN_SUBSET = 32


def perturb_inputs(x: OperatorInputs, std: dict[str, torch.Tensor | float],
                   draw: Callable[[str, torch.Tensor], torch.Tensor]) -> OperatorInputs:
    """x plus `std[name]` times `draw(name, tensor)` (a standard normal of the tensor's shape) on the particle
    features ("particles", channels last), the fluid grid ("fluid") and the mixing grid ("mixing", channels in
    dim 1); a std is one number or one per channel. Training's input noise and a rollout's `rollout_noise`."""
    def noisy(name: str, t: torch.Tensor, channel_dim: int) -> torch.Tensor:
        s = std[name]
        if torch.is_tensor(s):
            shape = [1] * t.ndim
            shape[channel_dim] = -1
            s = s.to(t.dtype).reshape(shape)
        return t + s * draw(name, t)

    return replace(x, particle_features=noisy("particles", x.particle_features, -1),
                   grid=noisy("fluid", x.grid, 1), mixing_grid=noisy("mixing", x.mixing_grid, 1))


def advance(net: MultiBranchOperator, inputs: OperatorInputs, norm: BedNormalizer, n_particles: int,
            generator: torch.Generator | None = None, chunk_size: int | None = None,
            step_scales: dict[str, torch.Tensor] | None = None, stability: BedStability | None = None,
            volume: torch.Tensor | None = None, net_view: OperatorInputs | None = None,
            rows: Callable[[torch.Tensor], torch.Tensor | None] | None = None) -> OperatorInputs:
    """The model's next state as the next input: decoded grids (with the stability options: `volume` (B,) is
    the solid volume to conserve, default the input's), particles re-sampled from the solid fraction.
    `step_scales` (`grid_step_scales`) for a residual model, whose grid outputs are scaled changes. `net_view`:
    what the net reads instead of `inputs` (a perturbed copy, `stability.rollout_noise`); the stability options
    and a residual model's base still use `inputs`. `rows`: which particles' displacement to decode
    (`next_inputs`)."""
    # with mixing=advect the step replaces the decoded mixing grid: the mixing off-branch is left out altogether
    advected = stability is not None and stability.mixing == "advect"
    tokens, cond = net.latents(inputs if net_view is None else net_view, off_branches=not advected)
    fields = apply_stability(decode_grid(net, tokens, cond, inputs, chunk_size, step_scales, mixing=not advected),
                             inputs, norm, stability, volume)
    return next_inputs(net, tokens, cond, fields, inputs, norm, n_particles, generator, chunk_size, rows)
