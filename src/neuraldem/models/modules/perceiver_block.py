"""Perceiver cross-attention block with DiT modulation: queries attend to a set of latent tokens.

Queries never attend to each other, so each query's output depends only on itself and the latents; this is
what makes the decoder a neural field that can be evaluated at any number of points.
"""

from __future__ import annotations

import torch
from torch import nn

from neuraldem.models.modules.attention import attend, check_heads
from neuraldem.models.modules.dit_modulation import DitModulation, dit_norm, modulate
from neuraldem.models.modules.mlp import Mlp


class DitPerceiverBlock(nn.Module):
    """q + gate * CrossAttn(mod(norm(q)), norm(latents)), then q + gate * MLP(mod(norm(q))).

    `key_value(latents)` is split from `forward` so chunked decoding projects the latents only once.
    """

    def __init__(self, dim: int, num_heads: int, cond_dim: int, mlp_ratio: float = 4.0) -> None:
        super().__init__()
        check_heads(dim, num_heads)
        self.num_heads = num_heads
        self.query_norm = dit_norm(dim)
        self.latent_norm = nn.LayerNorm(dim, eps=1e-6)
        self.q = nn.Linear(dim, dim)
        self.kv = nn.Linear(dim, 2 * dim)
        self.attn_out = nn.Linear(dim, dim)
        self.mlp_norm = dit_norm(dim)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))
        self.modulation = DitModulation(dim, cond_dim, n_vectors=6)

    def key_value(self, latents: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Latent tokens (B, L, dim) -> keys and values, each (B, L, dim)."""
        k, v = self.kv(self.latent_norm(latents)).chunk(2, dim=-1)
        return k, v

    def forward(self, queries: torch.Tensor, key_value: tuple[torch.Tensor, torch.Tensor],
                cond: torch.Tensor) -> torch.Tensor:
        attn_shift, attn_scale, attn_gate, mlp_shift, mlp_scale, mlp_gate = self.modulation(cond)
        q = self.q(modulate(self.query_norm(queries), attn_shift, attn_scale))
        x = queries + attn_gate * self.attn_out(attend(q, *key_value, self.num_heads))
        return x + mlp_gate * self.mlp(modulate(self.mlp_norm(x), mlp_shift, mlp_scale))
