import pytest
import torch

from neuraldem.errors import ConfigError
from neuraldem.models.modules.supernode_pooling import SupernodePooling, select_supernodes


def make_pooling(**kwargs) -> SupernodePooling:
    torch.manual_seed(0)
    args = {"in_channels": 3, "dim": 16, "radius": 0.3, "n_supernodes": 8, "max_neighbours": 64}
    return SupernodePooling(**(args | kwargs))


def particles(batch: int = 2, n: int = 40) -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(1)
    return torch.rand(batch, n, 3, generator=generator), torch.randn(batch, n, 3, generator=generator)


@pytest.mark.parametrize("mode", ["relative", "absolute", "both"])
def test_shape(mode):
    pos, feat = particles()
    assert make_pooling(position_mode=mode)(pos, feat).shape == (2, 8, 16)


def test_invariant_to_particle_order_for_fixed_supernodes():
    pooling = make_pooling()
    pos, feat = particles()
    supernodes = torch.tensor([[0, 5, 9, 13], [1, 2, 30, 39]])
    perm = torch.randperm(40)
    inverse = torch.argsort(perm)  # new index of old particle i
    out = pooling(pos, feat, supernodes)
    permuted = pooling(pos[:, perm], feat[:, perm], inverse[supernodes])
    assert torch.allclose(out, permuted, atol=1e-6)


def test_token_is_mean_of_messages_within_radius():
    pooling = make_pooling(radius=0.4)
    pos, feat = particles(batch=1, n=30)
    out = pooling(pos, feat, torch.tensor([[3]]))
    centre = pos[0, 3]
    near = (pos[0] - centre).norm(dim=-1) <= 0.4
    messages = pooling.message(torch.cat([
        feat[0, near], pooling.pos_embed(pos[0, near] - centre), pooling.pos_embed(pos[0, near])], dim=-1))
    assert 1 < near.sum() < 30
    assert torch.allclose(out[0, 0], messages.mean(0), atol=1e-5)


def test_samples_do_not_exchange_messages():
    pooling = make_pooling()
    pos, feat = particles()
    supernodes = torch.tensor([[0, 1], [0, 1]])
    out = pooling(pos, feat, supernodes)
    other = feat.clone()
    other[1] = torch.randn(40, 3)
    assert torch.equal(pooling(pos, other, supernodes)[0], out[0])


def test_supernode_choice_random_in_training_fixed_in_eval():
    pooling = make_pooling(n_supernodes=8, n_supernodes_eval=12)
    pos, feat = particles()
    assert pooling.train()(pos, feat).shape == (2, 8, 16)
    torch.manual_seed(1)
    a = pooling.choose_supernodes(pos)
    torch.manual_seed(2)
    assert not torch.equal(a, pooling.choose_supernodes(pos))
    pooling.eval()
    assert pooling(pos, feat).shape == (2, 12, 16)
    assert torch.equal(pooling(pos, feat), pooling(pos, feat))


def test_select_supernodes_draws_distinct_particles():
    idx = select_supernodes(3, 20, 20, device=torch.device("cpu"))
    assert all(sorted(row.tolist()) == list(range(20)) for row in idx)
    with pytest.raises(ConfigError, match="model.net.n_supernodes"):
        select_supernodes(1, 5, 6, device=torch.device("cpu"))


def test_validation():
    with pytest.raises(ValueError, match="position_mode 'polar' is not one of"):
        make_pooling(position_mode="polar")
    with pytest.raises(ValueError, match="particle features"):
        make_pooling()(*particles()[:1], torch.randn(2, 40, 4))


def test_a_given_graph_is_the_one_it_would_find_and_reads_only_its_particles():
    """A caller that already found the graph (a rollout step, for the next step) passes it: the same tokens;
    features of particles outside the graph are never read; one sample finds the edges it finds within a batch."""
    pooling = make_pooling(radius=0.2, max_neighbours=5).eval()
    pos, feat = particles(batch=2, n=60)
    graph = pooling.graph(pos)
    assert torch.equal(pooling(pos, feat, graph=graph), pooling(pos, feat))
    read = graph.particles_read()
    assert 0 < len(read) < 120 and torch.equal(read, torch.unique(graph.edges[1]))
    unread = torch.ones(120, dtype=torch.bool)
    unread[read] = False
    other = feat.reshape(-1, 3).clone()
    other[unread] = 1e6
    assert torch.equal(pooling(pos, other.reshape(2, 60, 3), graph=graph), pooling(pos, feat, graph=graph))
    one = pooling.graph(pos[1:], graph.supernode_idx[1:])
    in_batch = graph.edges[:, graph.edges[0] >= graph.supernode_idx.shape[1]]
    shifted = in_batch - torch.tensor([[graph.supernode_idx.shape[1]], [60]])
    assert torch.equal(one.edges, shifted)


def test_eval_supernodes_first_drawn_in_inference_mode_serve_a_gradient():
    """Eval-mode supernodes are drawn once per shape; the first draw may come from a rollout in inference mode,
    and a later eval-mode pass that keeps a gradient must still backpropagate through the pooling."""
    from neuraldem.models.modules.supernode_pooling import _eval_supernodes

    _eval_supernodes.cache_clear()
    pool = make_pooling().eval()
    pos, feat = particles(batch=1, n=37)
    feat.requires_grad_(True)
    with torch.inference_mode():
        first = pool(pos, feat.detach())
    again = pool(pos, feat)
    again.sum().backward()
    assert feat.grad is not None and torch.equal(first, again.detach())
