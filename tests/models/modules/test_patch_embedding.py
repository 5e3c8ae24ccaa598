import math

import pytest
import torch

from neuraldem.errors import ConfigError
from neuraldem.models.modules.patch_embedding import (
    PatchEmbedding,
    PatchUnembedding,
    cell_centres,
    patch_grid_shape,
)


def patchify(grid: torch.Tensor, patch: tuple[int, ...]) -> torch.Tensor:
    """Reference: (B, C, *grid) -> (B, n_patches, C * prod(patch)), patches in C order, values (C, p...)."""
    batch, channels, *shape = grid.shape
    ndim = len(shape)
    pairs = list(zip(shape, patch, strict=True))
    split = grid.reshape(batch, channels, *[v for g, p in pairs for v in (g // p, p)])
    order = [0] + [2 + 2 * i for i in range(ndim)] + [1] + [3 + 2 * i for i in range(ndim)]
    return split.permute(order).reshape(batch, math.prod(g // p for g, p in pairs), -1)


def raw_value_embedding(channels: int, patch: tuple[int, ...]) -> PatchEmbedding:
    """A patch embedding whose token is exactly the patch's values (plus the position embedding)."""
    dim = channels * math.prod(patch)
    embed = PatchEmbedding(channels, dim, patch)
    with torch.no_grad():
        embed.proj.weight.copy_(torch.eye(dim).view(dim, channels, *patch))
        embed.proj.bias.zero_()
    return embed


@pytest.mark.parametrize(("grid_shape", "patch"), [((12, 1, 30), (2, 1, 2)), ((8, 4, 8), (4, 4, 4)),
                                                   ((6, 9), (3, 3))])
def test_shapes(grid_shape, patch):
    tokens = PatchEmbedding(4, 16, patch)(torch.rand(2, 4, *grid_shape))
    n_patches = math.prod(g // p for g, p in zip(grid_shape, patch, strict=True))
    assert tokens.shape == (2, n_patches, 16)
    assert PatchUnembedding(16, 4, patch)(tokens, grid_shape).shape == (2, 4, *grid_shape)


@pytest.mark.parametrize(("grid_shape", "patch"), [((12, 1, 30), (2, 1, 2)), ((6, 4), (3, 2))])
def test_tokens_are_patches_in_c_order_and_unembedding_inverts_them(grid_shape, patch):
    grid = torch.rand(2, 3, *grid_shape)
    embed = raw_value_embedding(3, patch)
    tokens = embed(grid) - embed.pos_embed(cell_centres(patch_grid_shape(grid_shape, patch)))
    assert torch.allclose(tokens, patchify(grid, patch), atol=1e-5)

    dim = 3 * math.prod(patch)
    unembed = PatchUnembedding(dim, 3, patch)
    with torch.no_grad():
        unembed.proj.weight.copy_(torch.eye(dim))
        unembed.proj.bias.zero_()
    assert torch.allclose(unembed(patchify(grid, patch), grid_shape), grid)


def test_position_embedding_tells_patches_apart():
    tokens = PatchEmbedding(1, 16, (2, 1, 2))(torch.zeros(1, 1, 4, 1, 4))
    assert torch.unique(tokens.round(decimals=4), dim=1).shape[1] == 4


def test_cell_centres():
    assert torch.allclose(cell_centres((2, 1)), torch.tensor([[0.25, 0.5], [0.75, 0.5]]))
    assert cell_centres((12, 1, 30)).shape == (360, 3)


def test_validation():
    with pytest.raises(ConfigError, match="does not split"):
        PatchEmbedding(1, 16, (4, 4, 4))(torch.rand(1, 1, 12, 1, 30))
    with pytest.raises(ValueError, match="not 2 or 3 positive cell counts"):
        PatchEmbedding(1, 16, (4,))
    with pytest.raises(ValueError, match="not 2 or 3 positive cell counts"):
        PatchEmbedding(1, 16, (4, 0))


def test_cell_centres_first_asked_for_in_inference_mode_serve_training():
    """They are made once per grid (a rollout step asks often); the first ask may come from a rollout, in
    inference mode, and a later training step must still backpropagate through them."""
    from neuraldem.models.modules.patch_embedding import _cell_centres, cell_centres

    _cell_centres.cache_clear()
    with torch.inference_mode():
        first = cell_centres((3, 1, 5))
    weight = torch.ones(3, requires_grad=True)
    (cell_centres((3, 1, 5)) * weight).sum().backward()
    assert not first.is_inference() and torch.equal(weight.grad, cell_centres((3, 1, 5)).sum(0))
