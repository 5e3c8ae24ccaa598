import torch

from neuraldem.models.modules.perceiver_block import DitPerceiverBlock
from tests.models.nets import activate_modulations


def test_fresh_block_is_identity_on_queries():
    block = DitPerceiverBlock(dim=16, num_heads=2, cond_dim=8)
    queries, latents = torch.randn(2, 7, 16), torch.randn(2, 3, 16)
    assert torch.equal(block(queries, block.key_value(latents), torch.randn(2, 8)), queries)


def test_queries_read_latents_but_not_each_other():
    torch.manual_seed(0)
    block = activate_modulations(DitPerceiverBlock(dim=16, num_heads=2, cond_dim=8))
    queries, latents, cond = torch.randn(2, 7, 16), torch.randn(2, 3, 16), torch.randn(2, 8)
    out = block(queries, block.key_value(latents), cond)
    assert out.shape == (2, 7, 16)
    assert not torch.allclose(block(queries, block.key_value(torch.randn_like(latents)), cond), out)
    alone = block(queries[:, 2:3], block.key_value(latents), cond)
    assert torch.allclose(alone, out[:, 2:3], atol=1e-6)
