import torch

from neuraldem.models.modules.perceiver_decoder import PerceiverDecoder
from tests.models.nets import activate_modulations


def make_decoder() -> PerceiverDecoder:
    torch.manual_seed(0)
    return activate_modulations(PerceiverDecoder(dim=16, out_dim=3, num_heads=2, cond_dim=8))


def inputs(n_queries: int = 50) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(1)
    return (torch.randn(2, 6, 16, generator=generator), torch.rand(2, n_queries, 3, generator=generator),
            torch.randn(2, 8, generator=generator))


def test_shape():
    latents, query_pos, cond = inputs()
    assert make_decoder()(latents, query_pos, cond).shape == (2, 50, 3)


def test_chunked_equals_unchunked():
    decoder = make_decoder()
    latents, query_pos, cond = inputs()
    full = decoder(latents, query_pos, cond)
    for chunk_size in (1, 7, 50, 64):
        assert torch.allclose(decoder(latents, query_pos, cond, chunk_size=chunk_size), full, atol=1e-6)


def test_decoding_a_subset_gives_the_subset_of_all():
    """Discretisation convergence: the value at a point does not depend on which other points are decoded."""
    decoder = make_decoder()
    latents, query_pos, cond = inputs()
    subset = torch.tensor([3, 17, 18, 41])
    full = decoder(latents, query_pos, cond)
    assert torch.allclose(decoder(latents, query_pos[:, subset], cond), full[:, subset], atol=1e-6)


def test_output_depends_on_latents_and_condition():
    decoder = make_decoder()
    latents, query_pos, cond = inputs()
    full = decoder(latents, query_pos, cond)
    assert not torch.allclose(decoder(torch.randn_like(latents), query_pos, cond), full)
    assert not torch.allclose(decoder(latents, query_pos, cond + 1), full)
