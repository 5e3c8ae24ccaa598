import pytest
import torch

from neuraldem.models.multi_branch_operator import MAIN_BRANCHES, MultiBranchOperator, OperatorInputs
from neuraldem.models.registry import build_net
from tests.models.nets import activate_modulations, fit

GRID = (12, 1, 30)  # pseudo-2D fluidized bed


def tiny(**overrides) -> MultiBranchOperator:
    torch.manual_seed(0)
    return build_net("fb_tiny", **overrides)


def inputs(model: MultiBranchOperator, grid_shape=GRID, n_particles: int = 64) -> OperatorInputs:
    x = model.example_inputs(batch_size=2, n_particles=n_particles, grid_shape=grid_shape,
                             generator=torch.Generator().manual_seed(1))
    x.supernode_idx = torch.stack([torch.arange(16), torch.arange(16) * 2])  # fixed supernodes
    return x


def loss_against(model: MultiBranchOperator, x: OperatorInputs, target: dict[str, torch.Tensor]):
    out = model(x)
    return sum((out[name] - target[name]).square().mean() for name in out)


def test_output_per_branch_on_pseudo_2d_grid():
    model = tiny()
    out = model(inputs(model))
    assert {name: tuple(v.shape) for name, v in out.items()} == {
        "particles": (2, 64, 3), "fluid": (2, 360, 4), "mixing": (2, 360, 1)}


def test_branch_channels_are_configurable():
    model = tiny(particle_channels=6, fluid_channels=5, mixing_channels=2, patch_size=[4, 1, 6])
    out = model(inputs(model))
    assert [v.shape[-1] for v in out.values()] == [6, 5, 2]


def test_only_requested_branches_are_decoded():
    model = tiny()
    x = inputs(model)
    x.query_pos = {"fluid": x.query_pos["fluid"][:, :10]}
    assert list(model(x)) == ["fluid"]
    x.query_pos = {"pressure": x.query_pos["fluid"]}
    with pytest.raises(ValueError, match="unknown branches"):
        model(x)


def test_chunked_equals_unchunked_and_subset_equals_subset_of_all():
    model = activate_modulations(tiny())
    x = inputs(model)
    full = model(x)
    chunked = model(x, chunk_size=50)
    subset = torch.tensor([1, 2, 40, 63])
    x.query_pos = {name: pos[:, subset] for name, pos in x.query_pos.items()}
    sub = model(x)
    for name in full:
        assert torch.allclose(chunked[name], full[name], atol=1e-6)
        assert torch.allclose(sub[name], full[name][:, subset], atol=1e-6)


def test_grid_only_model_has_no_particle_branch_and_ignores_particles():
    full, grid_only = tiny(), tiny(particle_branch=False)
    assert grid_only.branches == ("fluid", "mixing") and "particles" not in grid_only.encoders
    assert sum(p.numel() for p in grid_only.parameters()) < sum(p.numel() for p in full.parameters())
    grid_only = activate_modulations(grid_only)
    x = inputs(grid_only)
    assert "particles" not in x.query_pos
    out = grid_only(x)
    assert {name: tuple(v.shape) for name, v in out.items()} == {"fluid": (2, 360, 4), "mixing": (2, 360, 1)}
    x.particle_pos, x.particle_features = torch.rand_like(x.particle_pos), torch.rand_like(x.particle_features)
    again = grid_only(x)
    assert all(torch.equal(again[name], out[name]) for name in out)
    x.grid = torch.rand_like(x.grid)
    assert not torch.allclose(grid_only(x)["fluid"], out["fluid"])
    x.query_pos = {"particles": x.particle_pos}
    with pytest.raises(ValueError, match="unknown branches"):
        grid_only(x)


def test_off_branch_inputs_do_not_change_main_outputs():
    model = activate_modulations(tiny())
    x = inputs(model)
    out = model(x)
    x.mixing_grid = torch.rand_like(x.mixing_grid)
    changed = model(x)
    assert not torch.allclose(changed["mixing"], out["mixing"])
    for name in MAIN_BRANCHES:
        assert torch.equal(changed[name], out[name])


def test_latents_without_the_off_branches_are_the_main_tokens_bit_for_bit():
    """A caller that decodes no off-branch (a rollout that advects the mixing) may leave them out: the main
    tokens are the same, and the off-branch's encoder is never run."""
    model = activate_modulations(tiny()).eval()
    x = inputs(model)
    calls = []
    model.encoders["mixing"].register_forward_hook(lambda *args: calls.append(1))
    full, cond = model.latents(x)
    assert calls == [1]
    main, cond_main = model.latents(x, off_branches=False)
    assert calls == [1] and set(main) == set(MAIN_BRANCHES) and set(full) == set(MAIN_BRANCHES) | {"mixing"}
    assert torch.equal(cond, cond_main)
    for name in MAIN_BRANCHES:
        assert torch.equal(main[name], full[name])
    torch.testing.assert_close(model.decode(main, cond, {"fluid": x.query_pos["fluid"]})["fluid"],
                               model(x)["fluid"], rtol=0, atol=0)


def test_off_branch_reads_main_branches():
    model = activate_modulations(tiny())
    x = inputs(model)
    out = model(x)
    x.grid = torch.rand_like(x.grid)
    assert not torch.allclose(model(x)["mixing"], out["mixing"])


def test_off_branch_loss_has_zero_gradient_for_main_branch_parameters():
    model = activate_modulations(tiny())
    model(inputs(model))["mixing"].square().mean().backward()
    off_names = [n for n, p in model.named_parameters() if "mixing" in n.split(".")]
    assert off_names and all(dict(model.named_parameters())[n].grad.abs().sum() > 0 for n in off_names[:3])
    for name, param in model.named_parameters():
        if "mixing" not in name.split("."):
            assert param.grad is None or torch.all(param.grad == 0), name


def test_conditioning_takes_effect_after_one_training_step():
    model = tiny()
    x = inputs(model)
    other = OperatorInputs(**{**vars(x), "scalars": x.scalars + 0.3})
    fresh, fresh_other = model(x), model(other)  # fresh DiT blocks are the identity: scalars do nothing
    assert all(torch.equal(fresh[name], fresh_other[name]) for name in fresh)
    target = {name: torch.randn_like(v) for name, v in model(x).items()}
    fit(model, lambda: loss_against(model, x, target), steps=1)
    after, after_other = model(x), model(other)
    for name in after:
        assert not torch.allclose(after[name], after_other[name]), name


def test_supernodes_are_random_in_training_and_fixed_in_eval():
    model = activate_modulations(tiny())
    x = inputs(model)
    x.supernode_idx = None
    assert torch.equal(model.eval()(x)["particles"], model(x)["particles"])
    torch.manual_seed(3)
    a = model.train()(x)["particles"]
    assert not torch.allclose(a, model(x)["particles"])


def test_overfits_a_tiny_batch():
    model = tiny()
    x = inputs(model, grid_shape=(4, 1, 6), n_particles=32)
    target = {name: torch.sin(6 * x.query_pos[name][..., :1]).expand_as(v) for name, v in model(x).items()}
    losses = fit(model, lambda: loss_against(model, x, target), steps=60, lr=3e-3)
    assert losses[-1] < losses[0] / 10, losses[::10]
    print(f"loss {losses[0]:.3g} -> {losses[-1]:.3g}")


def test_the_scalar_embedding_scale_sets_how_fast_the_conditioning_turns():
    """With the positions' coord_scale (1000, the default, and the velocity embedding scale of bed nets trained with
    1000) the inlet velocity's embedding moves between two velocities 0.002 of the range apart about as far as
    between two 0.1 apart, so a net can answer one unseen velocity unlike its neighbours; scalar_coord_scale=10
    keeps nearby velocities nearby. An old net's config (no scalar_coord_scale) builds the same net as before."""
    def turn(net: MultiBranchOperator) -> float:
        e = net.conditioner.embeds[0](torch.tensor([[0.860], [0.862], [0.960]]))
        return float((e[0] - e[1]).norm() / (e[0] - e[2]).norm())

    assert turn(tiny(scalar_coord_scale=10.0)) < 0.05
    assert turn(tiny()) > 0.3
    assert tiny().conditioner.embeds[0].coord_scale == 1000.0


def test_scalar_coord_scale_is_checked():
    from neuraldem.errors import ConfigError
    from neuraldem.models.schemas import MultiBranchOperatorNet

    with pytest.raises(ConfigError, match=r"model\.net\.scalar_coord_scale=0 is invalid"):
        MultiBranchOperatorNet.validate({"scalar_coord_scale": 0})
