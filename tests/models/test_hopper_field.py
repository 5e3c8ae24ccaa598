import pytest
import torch

from neuraldem.errors import ConfigError
from neuraldem.models.hopper_field import BRANCH_CHANNELS, HopperFieldModel
from neuraldem.models.registry import build_net
from tests.models.nets import activate_modulations, fit


def tiny(**overrides) -> HopperFieldModel:
    torch.manual_seed(0)
    return build_net("hopper_tiny", **overrides)


def inputs(model: HopperFieldModel, n_queries: int = 40) -> dict[str, torch.Tensor]:
    return model.example_inputs(batch_size=2, n_queries=n_queries, generator=torch.Generator().manual_seed(1))


def loss_against(model: HopperFieldModel, x: dict[str, torch.Tensor], target: dict[str, torch.Tensor]):
    out = model(**x)
    return sum((out[name] - target[name]).square().mean() for name in out)


def test_output_per_branch():
    branches = ["occupancy", "transport", "residence", "displacement"]
    model = tiny(branches=branches)
    out = model(**inputs(model))
    assert {name: tuple(v.shape) for name, v in out.items()} == {
        name: (2, 40, BRANCH_CHANNELS[name]) for name in branches}


def test_branches_can_be_queried_at_their_own_points():
    model = activate_modulations(tiny())
    x = inputs(model)
    full = model(**x)
    own = model(x["scalars"], {"transport": x["query_pos"][:, :5]})
    assert list(own) == ["transport"]
    assert torch.allclose(own["transport"], full["transport"][:, :5], atol=1e-6)
    with pytest.raises(ValueError, match="unknown branches"):
        model(x["scalars"], {"pressure": x["query_pos"]})


def test_chunked_equals_unchunked_and_subset_equals_subset_of_all():
    model = activate_modulations(tiny())
    x = inputs(model)
    full = model(**x)
    chunked = model(**x, chunk_size=6)
    subset = torch.tensor([0, 7, 8, 39])
    sub = model(x["scalars"], x["query_pos"][:, subset])
    for name in full:
        assert torch.allclose(chunked[name], full[name], atol=1e-6)
        assert torch.allclose(sub[name], full[name][:, subset], atol=1e-6)


def test_branches_are_independent():
    model = activate_modulations(tiny())
    model(**inputs(model))["occupancy"].sum().backward()
    for name in ("transport", "residence"):
        assert all(p.grad is None for p in model.branch_nets[name].parameters())


def test_conditioning_takes_effect_after_one_training_step():
    model = tiny()
    x = inputs(model)
    other = dict(x, scalars=x["scalars"] + torch.tensor([0.0, 0.3, 0.0, 0.0]))
    before, before_other = model(**x), model(**other)
    # fresh DiT blocks are the identity and the decoder's gates are zero: the scalars have no effect yet
    assert all(torch.equal(before[name], before_other[name]) for name in before)
    target = {name: torch.randn_like(v) for name, v in before.items()}
    fit(model, lambda: loss_against(model, x, target), steps=1)
    after, after_other = model(**x), model(**other)
    assert any(not torch.allclose(after[name], after_other[name]) for name in after)


def test_overfits_a_tiny_batch():
    model = tiny()
    x = inputs(model, n_queries=32)
    target = {name: torch.sin(6 * x["query_pos"][..., :n]) + x["scalars"][:, None, :1]
              for name, n in BRANCH_CHANNELS.items() if name in model.branches}
    losses = fit(model, lambda: loss_against(model, x, target), steps=60, lr=3e-3)
    assert losses[-1] < losses[0] / 10, losses[::10]
    print(f"loss {losses[0]:.3g} -> {losses[-1]:.3g}")


def test_validation():
    with pytest.raises(ConfigError, match="model.net.branches"):
        tiny(branches=["occupancy", "pressure"])
    with pytest.raises(ConfigError, match="model.net.n_latent_tokens"):
        tiny(n_latent_tokens=0)
