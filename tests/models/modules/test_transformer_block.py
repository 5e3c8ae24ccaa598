import pytest
import torch

from neuraldem.models.modules.transformer_block import DitTransformerBlock
from tests.models.nets import activate_modulations


def test_fresh_block_is_identity():
    block = DitTransformerBlock(dim=16, num_heads=2, cond_dim=8)
    x = torch.randn(2, 5, 16)
    assert torch.equal(block(x, torch.randn(2, 8)), x)


def test_trained_block_mixes_tokens_and_uses_condition():
    torch.manual_seed(0)
    block = activate_modulations(DitTransformerBlock(dim=16, num_heads=2, cond_dim=8))
    x, cond = torch.randn(2, 5, 16), torch.randn(2, 8)
    out = block(x, cond)
    assert out.shape == x.shape
    assert not torch.allclose(out, x)
    assert not torch.allclose(block(x, cond + 1), out)
    changed = x.clone()
    changed[:, 0] = torch.randn(2, 16)  # attention: another token's output changes too
    assert not torch.allclose(block(changed, cond)[:, 1], out[:, 1])


def test_validation():
    with pytest.raises(ValueError, match="not a positive multiple of 3 heads"):
        DitTransformerBlock(dim=16, num_heads=3, cond_dim=8)
