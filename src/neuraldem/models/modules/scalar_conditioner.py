"""Embeds the scalar simulation parameters (time, angle, frictions, inlet velocity, ...) into one vector.

Which scalars (and how many) is an experiment choice: conditioning ablations only change `n_scalars`.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from neuraldem.models.modules.mlp import Mlp
from neuraldem.models.modules.position_embedding import DEFAULT_COORD_SCALE, ContinuousSincosEmbed


class ScalarConditioner(nn.Module):
    """(B, S) normalised scalars -> (B, cond_dim) conditioning vector.

    Each scalar gets its own sin-cos embedding + MLP (no shared weights, so the model knows which scalar is
    which); the per-scalar embeddings are concatenated and merged by a linear layer. Scalars are expected
    normalised by the data layer to roughly [0, 1] (the same convention as positions).
    """

    def __init__(self, n_scalars: int, dim: int, cond_dim: int,
                 coord_scales: float | Sequence[float] = DEFAULT_COORD_SCALE) -> None:
        super().__init__()
        self.n_scalars = n_scalars
        scales = [coord_scales] * n_scalars if isinstance(coord_scales, (int, float)) else list(coord_scales)
        if len(scales) != n_scalars:
            raise ValueError(f"{len(scales)} coordinate scales for {n_scalars} scalars")
        # one embedding per scalar: how finely a scalar is resolved is a property of that scalar (a smooth
        # dependence on a friction coefficient known at ~100 points must not be resolvable per point)
        self.embeds = nn.ModuleList(ContinuousSincosEmbed(dim, ndim=1, coord_scale=float(s)) for s in scales)
        self.per_scalar = nn.ModuleList(Mlp(dim, cond_dim, cond_dim) for _ in range(n_scalars))
        self.merge = nn.Linear(n_scalars * cond_dim, cond_dim)

    def forward(self, scalars: torch.Tensor) -> torch.Tensor:
        if scalars.ndim != 2 or scalars.shape[1] != self.n_scalars:
            raise ValueError(f"expected scalars of shape (B, {self.n_scalars}), got {tuple(scalars.shape)}")
        embedded = [mlp(embed(scalars[:, i:i + 1]))
                    for i, (embed, mlp) in enumerate(zip(self.embeds, self.per_scalar, strict=True))]
        return self.merge(torch.cat(embedded, dim=-1))
