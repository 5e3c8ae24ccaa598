"""Perceiver decoder: a neural field that evaluates latent tokens at arbitrary query positions.

Each query is embedded from its position only and cross-attends to the latent tokens; queries never interact,
so decoding any subset of points gives exactly the corresponding subset of decoding all of them
(discretisation convergence), and queries can be processed in chunks of bounded memory.
"""

from __future__ import annotations

import torch
from torch import nn

from neuraldem.models.modules.mlp import Mlp
from neuraldem.models.modules.perceiver_block import DitPerceiverBlock
from neuraldem.models.modules.position_embedding import ContinuousSincosEmbed


class PerceiverDecoder(nn.Module):
    """latents (B, L, dim), query_pos (B, Q, ndim) in [0, 1], cond (B, cond_dim) -> (B, Q, out_dim)."""

    def __init__(self, dim: int, out_dim: int, num_heads: int, cond_dim: int, ndim: int = 3,
                 mlp_ratio: float = 4.0) -> None:
        super().__init__()
        self.out_dim = out_dim
        self.query_embed = nn.Sequential(ContinuousSincosEmbed(dim, ndim), Mlp(dim, dim))
        self.block = DitPerceiverBlock(dim, num_heads, cond_dim, mlp_ratio)
        self.head = nn.Sequential(nn.LayerNorm(dim, eps=1e-6), Mlp(dim, dim, out_dim))

    def forward(self, latents: torch.Tensor, query_pos: torch.Tensor, cond: torch.Tensor,
                chunk_size: int | None = None) -> torch.Tensor:
        """`chunk_size` queries at a time (None: all at once); the result does not depend on it."""
        key_value = self.block.key_value(latents)
        chunks = [query_pos] if chunk_size is None else query_pos.split(chunk_size, dim=1)
        return torch.cat([self.head(self.block(self.query_embed(c), key_value, cond)) for c in chunks], dim=1)
