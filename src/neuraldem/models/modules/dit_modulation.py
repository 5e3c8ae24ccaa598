"""DiT (adaLN-Zero) modulation: scale, shift and gate vectors from the conditioning vector.

The projection is zero-initialised, so every gate starts at 0 and a fresh modulated block is the identity map;
the conditioning only takes effect once training has moved the projection away from zero.
"""

from __future__ import annotations

import torch
from torch import nn


def dit_norm(dim: int) -> nn.LayerNorm:
    """LayerNorm without its own affine parameters: the modulation provides scale and shift."""
    return nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)


def modulate(x: torch.Tensor, shift: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """Feature-wise affine modulation; scale is a residual around 1 so zeros mean "unchanged"."""
    return x * (1 + scale) + shift


class DitModulation(nn.Module):
    """SiLU -> Linear(cond_dim, n_vectors * dim) -> n_vectors tensors (B, 1, dim), broadcast over tokens."""

    def __init__(self, dim: int, cond_dim: int, n_vectors: int) -> None:
        super().__init__()
        self.n_vectors = n_vectors
        self.proj = nn.Linear(cond_dim, n_vectors * dim)
        nn.init.zeros_(self.proj.weight)
        nn.init.zeros_(self.proj.bias)

    def forward(self, cond: torch.Tensor) -> list[torch.Tensor]:
        return list(self.proj(nn.functional.silu(cond)).unsqueeze(1).chunk(self.n_vectors, dim=-1))

