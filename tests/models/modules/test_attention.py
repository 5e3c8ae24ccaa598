import pytest
import torch

from neuraldem.models.modules.attention import attend, check_heads, merge_heads, split_heads


def test_matches_explicit_softmax_attention():
    torch.manual_seed(0)
    q, k, v = torch.randn(2, 5, 8), torch.randn(2, 7, 8), torch.randn(2, 7, 8)
    heads = 2
    qh, kh, vh = (split_heads(t, heads) for t in (q, k, v))
    weights = torch.softmax(qh @ kh.transpose(-1, -2) / (4 ** 0.5), dim=-1)
    expected = merge_heads(weights @ vh)
    assert attend(q, k, v, heads).shape == (2, 5, 8)
    assert torch.allclose(attend(q, k, v, heads), expected, atol=1e-6)


def test_split_merge_roundtrip():
    x = torch.randn(2, 3, 12)
    assert split_heads(x, 4).shape == (2, 4, 3, 3)
    assert torch.equal(merge_heads(split_heads(x, 4)), x)


def test_heads_must_divide_dim():
    check_heads(12, 3)
    with pytest.raises(ValueError, match="not a positive multiple of 5 heads"):
        check_heads(12, 5)
    with pytest.raises(ValueError, match="not a positive multiple"):
        check_heads(0, 1)
