"""One field-based autoregressive step of the fluidized-bed model, in model units.

Shared by push-forward training and by rollouts, so both feed the model exactly the same kind of input:
the grid fields come from the decoded fluid and mixing branches; particles are never tracked: their input
positions are sampled anew from the predicted solid fraction (density proportional to it, uniform inside a
cell), and their input displacement is the particle branch decoded at those positions. A residual model
(`model.residual=true`) predicts the grid fields' change over the step, scaled per channel by the training
data's typical one-step change (`FbNormalizer.step_scale`); the next state is the input plus that change.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from neuraldem.data.fb_normalization import FbNormalizer
from neuraldem.models.modules.patch_embedding import cell_centres
from neuraldem.models.multi_branch_operator import MultiBranchOperator, OperatorInputs

SOLID_FRACTION_CHANNEL = 3  # fluid branch channels: fluid velocity (3), solid fraction (1)


def grid_queries(inputs: OperatorInputs) -> torch.Tensor:
    """(B, cells, 3) normalised cell centres of the fluid grid, in the C order of the decoded fields."""
    centres = cell_centres(inputs.grid.shape[2:], device=inputs.grid.device)
    return centres.expand(inputs.grid.shape[0], -1, -1)


def sample_positions(solid_fraction: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """(B, n, 3) normalised positions drawn with density proportional to the solid fraction (B, nx, ny, nz).

    Negative and non-finite values count as empty; a field with no solid anywhere is sampled uniformly
    (a diverging rollout is caught by its caller, not here)."""
    batch, shape = solid_fraction.shape[0], solid_fraction.shape[1:]
    weights = torch.nan_to_num(solid_fraction.reshape(batch, -1).float(), nan=0.0, posinf=0.0).clamp(min=0.0)
    weights = torch.where(weights.sum(dim=1, keepdim=True) > 0, weights, torch.ones_like(weights))
    device = generator.device if generator is not None else solid_fraction.device
    cell = torch.multinomial(weights.to(device), n, replacement=True, generator=generator)
    dims = torch.tensor(shape, device=device)
    ijk = torch.stack(torch.unravel_index(cell, tuple(shape)), dim=-1)
    offset = torch.rand(batch, n, 3, generator=generator, device=device)
    return ((ijk + offset) / dims).to(solid_fraction.device)


def grid_cells(grid: torch.Tensor) -> torch.Tensor:
    """(B, C, nx, ny, nz) -> (B, cells, C), cells in the C order of `grid_queries` (and of the targets)."""
    return grid.flatten(2).transpose(1, 2)


def grid_step_scales(norm: FbNormalizer) -> dict[str, torch.Tensor]:
    """Per-channel scale of one step's change, model units, for the fluid (fluid velocity + solid fraction) and
    mixing branches: a residual model's output times this is the change of the field over one step."""
    fluid = np.concatenate([norm.step_scale("fluid_velocity"), norm.step_scale("solid_fraction")])
    return {"fluid": torch.tensor(fluid, dtype=torch.float32),
            "mixing": torch.tensor(norm.step_scale("mixing"), dtype=torch.float32)}


def next_grid_fields(out: dict[str, torch.Tensor], inputs: OperatorInputs,
                     step_scales: dict[str, torch.Tensor] | None) -> dict[str, torch.Tensor]:
    """The decoded grid branches (B, cells, C) as next states, model units: the output itself, or for a
    residual model (`step_scales` given) the input plus the output times the step scale."""
    if step_scales is None:
        return {"fluid": out["fluid"], "mixing": out["mixing"]}
    return {name: grid_cells(grid) + out[name] * step_scales[name].to(out[name].device)
            for name, grid in (("fluid", inputs.grid), ("mixing", inputs.mixing_grid))}


def decode_grid(net: MultiBranchOperator, tokens: dict[str, torch.Tensor], cond: torch.Tensor,
                inputs: OperatorInputs, chunk_size: int | None = None,
                step_scales: dict[str, torch.Tensor] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Next fluid grid (B, 4, nx, ny, nz) and mixing grid (B, 1, nx, ny, nz), model units."""
    shape = inputs.grid.shape[2:]
    queries = grid_queries(inputs)
    out = next_grid_fields(net.decode(tokens, cond, {"fluid": queries, "mixing": queries}, chunk_size=chunk_size),
                           inputs, step_scales)
    batch = inputs.grid.shape[0]
    fluid = out["fluid"].transpose(1, 2).reshape(batch, -1, *shape)
    mixing = out["mixing"].transpose(1, 2).reshape(batch, -1, *shape)
    return fluid, mixing


def advance(net: MultiBranchOperator, inputs: OperatorInputs, norm: FbNormalizer, n_particles: int,
            generator: torch.Generator | None = None, chunk_size: int | None = None,
            step_scales: dict[str, torch.Tensor] | None = None) -> OperatorInputs:
    """The model's next state as the next input: decoded grids, particles re-sampled from the solid fraction.
    `step_scales` (`grid_step_scales`) for a residual model, whose grid outputs are scaled changes."""
    tokens, cond = net.latents(inputs)
    fluid, mixing = decode_grid(net, tokens, cond, inputs, chunk_size, step_scales)
    alpha = fluid[:, SOLID_FRACTION_CHANNEL] * norm.std["solid_fraction"][0] + norm.mean["solid_fraction"][0]
    positions = sample_positions(alpha, n_particles, generator)
    if net.particle_branch:
        displacement = net.decode(tokens, cond, {"particles": positions}, chunk_size=chunk_size)["particles"]
    else:  # a grid-only model reads no particles: the samples only show where the solid is
        displacement = inputs.particle_features.new_zeros(positions.shape[0], n_particles,
                                                          inputs.particle_features.shape[-1])
    return replace(inputs, particle_pos=positions, particle_features=displacement, grid=fluid, mixing_grid=mixing,
                   query_pos={}, supernode_idx=None)
