import math

import pytest
import torch

from neuraldem.models.modules.position_embedding import DEFAULT_COORD_SCALE, ContinuousSincosEmbed


@pytest.mark.parametrize("ndim", [1, 2, 3])
def test_shape_and_padding(ndim):
    embed = ContinuousSincosEmbed(dim=16, ndim=ndim)
    out = embed(torch.rand(2, 5, ndim))
    assert out.shape == (2, 5, 16)
    n_used = 2 * (16 // ndim // 2) * ndim
    assert torch.all(out[..., n_used:] == 0)  # leftover channels are zero padding
    assert out.abs().max() <= 1


def test_documented_formula_for_unit_range_coordinates():
    """Coordinates in [0, 1] are scaled by DEFAULT_COORD_SCALE; channels are [sin(.. * omega_k), cos(...)]."""
    embed = ContinuousSincosEmbed(dim=8, ndim=1, max_wavelength=10_000.0)
    x = torch.tensor([[0.3]])
    omega = 1.0 / 10_000.0 ** (torch.arange(4) / 4)
    phase = 0.3 * DEFAULT_COORD_SCALE * omega
    assert torch.allclose(embed(x)[0], torch.cat([phase.sin(), phase.cos()]), atol=1e-5)
    assert torch.allclose(embed(torch.zeros(1, 1))[0], torch.tensor([0.0] * 4 + [1.0] * 4))


def test_nearby_unit_range_coordinates_are_distinguished():
    embed = ContinuousSincosEmbed(dim=32, ndim=3)
    a, b = torch.full((1, 3), 0.5), torch.full((1, 3), 0.501)
    assert (embed(a) - embed(b)).norm() > 0.1
    assert math.isclose((embed(a) - embed(a.clone())).norm().item(), 0.0)


def test_rejects_too_small_dim_and_wrong_axes():
    with pytest.raises(ValueError, match="too narrow: it needs >= 6"):
        ContinuousSincosEmbed(dim=4, ndim=3)
    with pytest.raises(ValueError, match="3 coordinates"):
        ContinuousSincosEmbed(dim=12, ndim=3)(torch.rand(2, 2))
