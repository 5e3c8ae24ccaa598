"""ViT patch embedding for regular grids (2D or 3D) and its inverse, plus grid coordinate helpers.

Grid convention: a grid of shape (X, Y[, Z]) covers the domain box [0, 1]^ndim (the same normalised frame as
particle positions); cell (i, j, k) has its centre at ((i + 0.5) / X, (j + 0.5) / Y, (k + 0.5) / Z).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import lru_cache

import torch
from torch import nn

from neuraldem.errors import ConfigError
from neuraldem.models.modules.position_embedding import ContinuousSincosEmbed


def cell_centres(shape: Sequence[int], device: torch.device | str | None = None) -> torch.Tensor:
    """Normalised centres of all cells of a grid, (prod(shape), ndim), in C order (last axis fastest). Shared
    and read-only: made once per grid and device (a rollout step asks for them several times)."""
    return _cell_centres(tuple(int(n) for n in shape), torch.device(device) if device is not None else None)


@lru_cache(maxsize=32)
@torch.inference_mode(False)  # a plain tensor even when first asked for in inference mode: training reuses it
def _cell_centres(shape: tuple[int, ...], device: torch.device | None) -> torch.Tensor:
    axes = [(torch.arange(n, device=device, dtype=torch.float32) + 0.5) / n for n in shape]
    return torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, len(shape))


def as_patch_size(patch_size: Sequence[int]) -> tuple[int, ...]:
    """2 or 3 positive cell counts (a user's config is checked before, in `models.schemas`)."""
    size = tuple(int(p) for p in patch_size)
    if len(size) not in (2, 3) or min(size) <= 0:
        raise ValueError(f"patch size {tuple(patch_size)} is not 2 or 3 positive cell counts")
    return size


def patch_grid_shape(grid_shape: Sequence[int], patch_size: Sequence[int]) -> tuple[int, ...]:
    """Number of patches per axis; the grid must split into whole patches."""
    if len(grid_shape) != len(patch_size) or any(g % p for g, p in zip(grid_shape, patch_size, strict=True)):
        raise ConfigError(f"a grid of shape {tuple(grid_shape)} does not split into patches of size "
                          f"{tuple(patch_size)}: choose model.net.patch_size so each entry divides the grid")
    return tuple(g // p for g, p in zip(grid_shape, patch_size, strict=True))


class PatchEmbedding(nn.Module):
    """Grid (B, C, X, Y[, Z]) -> tokens (B, n_patches, dim), patches in C order.

    Each non-overlapping patch is embedded by a shared linear map (a strided convolution); the sin-cos
    embedding of the patch centre is added so tokens know where they are.
    """

    def __init__(self, in_channels: int, dim: int, patch_size: Sequence[int]) -> None:
        super().__init__()
        self.patch_size = as_patch_size(patch_size)
        conv = nn.Conv2d if len(self.patch_size) == 2 else nn.Conv3d
        self.proj = conv(in_channels, dim, kernel_size=self.patch_size, stride=self.patch_size)
        self.pos_embed = ContinuousSincosEmbed(dim, ndim=len(self.patch_size))

    def forward(self, grid: torch.Tensor) -> torch.Tensor:
        patches = patch_grid_shape(grid.shape[2:], self.patch_size)
        tokens = self.proj(grid).flatten(2).transpose(1, 2)
        return tokens + self.pos_embed(cell_centres(patches, device=grid.device)).to(tokens.dtype)


class PatchUnembedding(nn.Module):
    """Tokens (B, n_patches, dim) -> grid (B, C, X, Y[, Z]): each token predicts the values of its patch."""

    def __init__(self, dim: int, out_channels: int, patch_size: Sequence[int]) -> None:
        super().__init__()
        self.patch_size = as_patch_size(patch_size)
        self.out_channels = out_channels
        self.proj = nn.Linear(dim, out_channels * math.prod(self.patch_size))

    def forward(self, tokens: torch.Tensor, grid_shape: Sequence[int]) -> torch.Tensor:
        patches = patch_grid_shape(grid_shape, self.patch_size)
        ndim = len(patches)
        batch = tokens.shape[0]
        # (B, P1, P2[, P3], C, p1, p2[, p3]) -> (B, C, P1, p1, P2, p2[, P3, p3])
        values = self.proj(tokens).view(batch, *patches, self.out_channels, *self.patch_size)
        order = [0, ndim + 1] + [axis for i in range(ndim) for axis in (1 + i, ndim + 2 + i)]
        return values.permute(order).reshape(batch, self.out_channels, *grid_shape)
