import pytest
import torch

from neuraldem.errors import ConfigError
from neuraldem.models.gns import GraphNetworkSimulator, wall_distances
from neuraldem.models.schemas import GnsNet, build_net


def net(**kw):
    torch.manual_seed(0)
    args = {"n_scalars": 2, "history": 3, "n_extra_walls": 1, "radius": 1.5, "max_neighbours": 64, "dim": 16,
            "hidden": 16, "mlp_layers": 1, "steps": 2} | kw
    return GraphNetworkSimulator(**args).eval()


def sparse_inputs(n_graphs=2, n=30, seed=0):
    """Particles spread so that no node has many neighbours (torch_cluster keeps all of them)."""
    g = torch.Generator().manual_seed(seed)
    return net().example_inputs(n_graphs=n_graphs, n_particles=n, box=6.0, generator=g)


def test_shapes():
    m = net()
    x = sparse_inputs()
    out = m(**x)
    assert out.shape == (60, 3) and torch.isfinite(out).all()
    assert m.graph(x["pos"], x["batch"]).shape[0] == 2


def test_translation_invariance():
    m, x = net(), sparse_inputs()
    shift = torch.tensor([3.7, -12.0, 40.0])
    y = dict(x, pos=x["pos"] + shift, box_lo=x["box_lo"] + shift, box_hi=x["box_hi"] + shift)
    torch.testing.assert_close(m(**x), m(**y), atol=1e-5, rtol=1e-5)
    # shifting the particles but not the walls changes what they see (the test can fail)
    z = dict(x, pos=x["pos"] + torch.tensor([0.5, 0.0, 0.0]))
    assert not torch.allclose(m(**x), m(**z), atol=1e-4)


def test_permutation_equivariance():
    m, x = net(), sparse_inputs(n_graphs=1)
    perm = torch.randperm(30, generator=torch.Generator().manual_seed(1))
    y = dict(x, pos=x["pos"][perm], velocities=x["velocities"][perm], wall_distance=x["wall_distance"][perm])
    torch.testing.assert_close(m(**x)[perm], m(**y), atol=1e-5, rtol=1e-5)


def test_graphs_of_a_batch_do_not_interact():
    m, x = net(), sparse_inputs()
    alone = {k: v[:30] if v.shape[0] == 60 else v[:1] for k, v in x.items()}
    torch.testing.assert_close(m(**x)[:30], m(**alone), atol=1e-5, rtol=1e-5)


def test_wall_distances_are_clipped_at_the_radius():
    pos = torch.tensor([[0.5, 5.0, 9.9], [-0.2, 5.0, 5.0]])
    d = wall_distances(pos, torch.zeros(1, 3), torch.full((1, 3), 10.0), torch.zeros(2, dtype=torch.long), 2.0)
    torch.testing.assert_close(d[0], torch.tensor([0.25, 1.0, 1.0, 1.0, 1.0, 0.05]))
    assert d[1, 0] == -0.1  # outside the box: negative


@pytest.mark.parametrize(("key", "value"), [("radius", 0.0), ("steps", 0), ("history", -1), ("dim", 2.5)])
def test_bad_values_name_the_key(key, value):
    with pytest.raises(ConfigError, match=f"model.net.{key}={value} is invalid"):
        build_net({"_target_": GnsNet.target, "n_scalars": 2, key: value})
