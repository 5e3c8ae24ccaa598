import pytest
import torch

from neuraldem.models.modules.scalar_conditioner import ScalarConditioner


def test_shape():
    assert ScalarConditioner(n_scalars=3, dim=16, cond_dim=24)(torch.rand(5, 3)).shape == (5, 24)


@pytest.mark.parametrize("which", [0, 1, 2])
def test_every_scalar_changes_the_vector(which):
    torch.manual_seed(0)
    conditioner = ScalarConditioner(n_scalars=3, dim=16, cond_dim=16)
    scalars = torch.rand(1, 3)
    changed = scalars.clone()
    changed[0, which] += 0.1
    assert not torch.allclose(conditioner(scalars), conditioner(changed))


def test_scalars_are_not_interchangeable():
    torch.manual_seed(0)
    conditioner = ScalarConditioner(n_scalars=2, dim=16, cond_dim=16)
    swapped = conditioner(torch.tensor([[0.7, 0.2]]))
    assert not torch.allclose(conditioner(torch.tensor([[0.2, 0.7]])), swapped)


def test_validation():
    with pytest.raises(ValueError, match="1 coordinate scales for 2 scalars"):
        ScalarConditioner(n_scalars=2, dim=16, cond_dim=16, coord_scales=[1.0])
    with pytest.raises(ValueError, match=r"\(B, 2\)"):
        ScalarConditioner(n_scalars=2, dim=16, cond_dim=16)(torch.rand(4, 3))
