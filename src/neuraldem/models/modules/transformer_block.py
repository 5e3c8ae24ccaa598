"""Pre-norm transformer block (self-attention + MLP) with DiT modulation from the conditioning vector."""

from __future__ import annotations

import torch
from torch import nn

from neuraldem.models.modules.attention import attend, check_heads
from neuraldem.models.modules.dit_modulation import DitModulation, dit_norm, modulate
from neuraldem.models.modules.mlp import Mlp


class DitTransformerBlock(nn.Module):
    """x + gate * Attn(mod(norm(x))), then x + gate * MLP(mod(norm(x))); (B, N, dim), cond (B, cond_dim)."""

    def __init__(self, dim: int, num_heads: int, cond_dim: int, mlp_ratio: float = 4.0) -> None:
        super().__init__()
        check_heads(dim, num_heads)
        self.num_heads = num_heads
        self.attn_norm = dit_norm(dim)
        self.qkv = nn.Linear(dim, 3 * dim)
        self.attn_out = nn.Linear(dim, dim)
        self.mlp_norm = dit_norm(dim)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))
        self.modulation = DitModulation(dim, cond_dim, n_vectors=6)

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        attn_shift, attn_scale, attn_gate, mlp_shift, mlp_scale, mlp_gate = self.modulation(cond)
        q, k, v = self.qkv(modulate(self.attn_norm(x), attn_shift, attn_scale)).chunk(3, dim=-1)
        x = x + attn_gate * self.attn_out(attend(q, k, v, self.num_heads))
        return x + mlp_gate * self.mlp(modulate(self.mlp_norm(x), mlp_shift, mlp_scale))
