import torch

from neuraldem.models.modules.dit_modulation import DitModulation, dit_norm, modulate


def test_fresh_modulation_is_zero_and_broadcastable():
    vectors = DitModulation(dim=8, cond_dim=5, n_vectors=6)(torch.randn(3, 5))
    assert len(vectors) == 6
    for v in vectors:
        assert v.shape == (3, 1, 8)
        assert torch.all(v == 0)


def test_zero_shift_and_scale_leave_features_unchanged():
    x = torch.randn(2, 4, 8)
    zero = torch.zeros(2, 1, 8)
    assert torch.equal(modulate(x, zero, zero), x)
    assert torch.allclose(modulate(x, zero + 1, zero + 1), 2 * x + 1)


def test_modulation_depends_on_condition_once_trained():
    mod = DitModulation(dim=4, cond_dim=3, n_vectors=2)
    torch.nn.init.normal_(mod.proj.weight)
    a, b = mod(torch.zeros(1, 3)), mod(torch.ones(1, 3))
    assert not torch.allclose(a[0], b[0])


def test_norm_has_no_affine_parameters():
    norm = dit_norm(8)
    assert list(norm.parameters()) == []
    out = norm(torch.randn(2, 3, 8) * 5 + 2)
    assert torch.allclose(out.mean(-1), torch.zeros(2, 3), atol=1e-5)
