import torch

from neuraldem.models.modules.mlp import Mlp


def test_shapes():
    assert Mlp(4, 16)(torch.rand(2, 3, 4)).shape == (2, 3, 4)
    assert Mlp(4, 16, 7)(torch.rand(2, 3, 4)).shape == (2, 3, 7)
