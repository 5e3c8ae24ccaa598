"""Decoder-only NeuralDEM model for hoppers: fields predicted from the scalar parameters alone.

Hopper flows are slow and pseudo-steady, so the state at time t is determined by the scalars (time, outlet
angle, frictions, ...). Each branch starts from learned latent tokens, refines them with a few DiT transformer
blocks and decodes its field with a perceiver decoder. Branches never interact (the scalar conditioner is the
only shared part).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import nn

from neuraldem.models.modules.perceiver_decoder import PerceiverDecoder
from neuraldem.models.modules.position_embedding import DEFAULT_COORD_SCALE
from neuraldem.models.modules.scalar_conditioner import ScalarConditioner
from neuraldem.models.modules.transformer_block import DitTransformerBlock

# output channels per known hopper field
BRANCH_CHANNELS = {
    "occupancy": 1,  # logit of "a particle is here"
    "transport": 3,  # initial position of the particle that is here now (normalised coordinates)
    "residence": 1,  # residence time of the particle that is here (ML timesteps until it leaves)
    "displacement": 3,  # displacement over one ML timestep
}
DEFAULT_BRANCHES = ("occupancy", "transport", "residence")


class HopperBranch(nn.Module):
    """Learned latents -> DiT transformer blocks -> perceiver decoder, for one field."""

    def __init__(self, out_dim: int, dim: int, num_heads: int, cond_dim: int, n_latent_tokens: int,
                 depth: int, mlp_ratio: float) -> None:
        super().__init__()
        self.latents = nn.Parameter(torch.empty(n_latent_tokens, dim))
        nn.init.trunc_normal_(self.latents, std=0.02)
        self.blocks = nn.ModuleList(
            DitTransformerBlock(dim, num_heads, cond_dim, mlp_ratio) for _ in range(depth))
        self.decoder = PerceiverDecoder(dim, out_dim, num_heads, cond_dim, ndim=3, mlp_ratio=mlp_ratio)

    def forward(self, cond: torch.Tensor, query_pos: torch.Tensor, chunk_size: int | None) -> torch.Tensor:
        x = self.latents.expand(cond.shape[0], -1, -1)
        for block in self.blocks:
            x = block(x, cond)
        return self.decoder(x, query_pos, cond, chunk_size=chunk_size)


class HopperFieldModel(nn.Module):
    """Hopper fields at arbitrary points, conditioned on the simulation scalars.

    Args:
        n_scalars: number of conditioning scalars S (time first is a data-layer convention, not required).
        branches: field names, each from `BRANCH_CHANNELS` (sets its output channels).
        dim: token width; num_heads: attention heads (must divide dim); cond_dim: conditioning vector width.
        n_latent_tokens: learned latent tokens per branch (paper: 32); depth: transformer blocks per branch
        (paper: 1); mlp_ratio: MLP hidden width / dim.
        time_coord_scale / scalar_coord_scale: sin-cos scale of the first scalar (time) / of the others; the
        finest period is ~6/scale in normalised units, so a scale of 1000 resolves steps of 0.006, finer than
        the spacing of ~100 training parameter sets (it memorises them); see conf/model/hopper_tiny.yaml.

    forward(scalars (B, S), query_pos, chunk_size=None) -> {branch: (B, Q, channels)}.
    `scalars` are normalised by the data layer (roughly [0, 1]); `query_pos` are positions normalised to
    [0, 1] per axis of the domain box, either one (B, Q, 3) tensor for every branch or a mapping
    {branch: (B, Q_branch, 3)} to evaluate only those branches at their own points.
    """

    def __init__(self, n_scalars: int, branches: Sequence[str] = DEFAULT_BRANCHES, dim: int = 192,
                 num_heads: int = 3, cond_dim: int = 384, n_latent_tokens: int = 32, depth: int = 1,
                 mlp_ratio: float = 4.0, time_coord_scale: float = DEFAULT_COORD_SCALE,
                 scalar_coord_scale: float = DEFAULT_COORD_SCALE) -> None:
        super().__init__()
        self.branches = [str(b) for b in branches]
        unknown = sorted(set(self.branches) - set(BRANCH_CHANNELS))
        if unknown:
            raise ValueError(f"unknown branches {unknown}; known: {list(BRANCH_CHANNELS)}")
        self.n_scalars = n_scalars
        scales = [float(time_coord_scale)] + [float(scalar_coord_scale)] * (n_scalars - 1)
        self.conditioner = ScalarConditioner(n_scalars, dim, cond_dim, scales)
        self.branch_nets = nn.ModuleDict({
            name: HopperBranch(BRANCH_CHANNELS[name], dim, num_heads, cond_dim, n_latent_tokens, depth,
                               mlp_ratio)
            for name in self.branches
        })

    def forward(self, scalars: torch.Tensor, query_pos: torch.Tensor | Mapping[str, torch.Tensor],
                chunk_size: int | None = None) -> dict[str, torch.Tensor]:
        cond = self.conditioner(scalars)
        if isinstance(query_pos, torch.Tensor):
            query_pos = dict.fromkeys(self.branches, query_pos)
        unknown = sorted(set(query_pos) - set(self.branches))
        if unknown:
            raise ValueError(f"query positions for unknown branches {unknown}; branches: {self.branches}")
        return {name: self.branch_nets[name](cond, pos, chunk_size) for name, pos in query_pos.items()}

    def example_inputs(self, batch_size: int = 2, n_queries: int = 64,
                       generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
        """Random inputs of the right shapes (smoke tests, benchmarks): kwargs for `forward`."""
        device = self.conditioner.merge.weight.device
        return {
            "scalars": torch.rand(batch_size, self.n_scalars, generator=generator).to(device),
            "query_pos": torch.rand(batch_size, n_queries, 3, generator=generator).to(device),
        }
