"""Continuous sin-cos embedding of coordinates (any number of axes), as used for positions and scalars."""

from __future__ import annotations

import torch
from torch import nn

# Inputs in [0, 1] are multiplied by this, so the highest frequency (period 2*pi in scaled units) resolves
# ~0.6% of the domain and the lowest (period 2*pi*max_wavelength) stays monotonic over the whole domain.
DEFAULT_COORD_SCALE = 1000.0


class ContinuousSincosEmbed(nn.Module):
    """Embeds each of `ndim` coordinates with sines and cosines of geometrically spaced frequencies.

    Expected input: coordinates normalised to [0, 1] per axis by the data layer (relative offsets between two
    such coordinates lie in [-1, 1] and work the same way). They are multiplied by `coord_scale` internally.
    Each axis gets `dim // ndim` channels (rounded down to even); leftover channels are zero.
    Input (..., ndim) -> output (..., dim).
    """

    def __init__(self, dim: int, ndim: int, *, max_wavelength: float = 10_000.0,
                 coord_scale: float = DEFAULT_COORD_SCALE) -> None:
        super().__init__()
        self.dim, self.ndim = dim, ndim
        if ndim <= 0 or dim < 2 * ndim:
            raise ValueError(f"an embedding of width {dim} is too narrow: it needs >= {2 * ndim} to embed "
                             f"{ndim} coordinate axes")
        self.coord_scale = float(coord_scale)
        n_freq = dim // ndim // 2
        self.n_padding = dim - 2 * n_freq * ndim
        exponent = torch.arange(n_freq, dtype=torch.float32) / n_freq
        self.register_buffer("omega", 1.0 / max_wavelength ** exponent, persistent=False)

    def forward(self, coords: torch.Tensor) -> torch.Tensor:
        if coords.shape[-1] != self.ndim:
            raise ValueError(f"expected {self.ndim} coordinates in the last axis, got {tuple(coords.shape)}")
        # float32 even under autocast: scaled coordinates need the precision
        phase = (coords.float() * self.coord_scale).unsqueeze(-1) * self.omega  # (..., ndim, n_freq)
        emb = torch.cat([phase.sin(), phase.cos()], dim=-1).flatten(-2)
        if self.n_padding:
            emb = nn.functional.pad(emb, (0, self.n_padding))
        return emb.to(coords.dtype)
