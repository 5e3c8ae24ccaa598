"""BedModule on the real fb_tiny dataset: a tiny model learns, push-forward unrolls the rollout step,
checkpoints carry the data's metadata, and configs that cannot fit the data fail before training."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import pytest
import torch

from neuraldem.errors import ConfigError
from neuraldem.models.registry import net_config
from neuraldem.scenes.fluidized_bed.surrogate import module as fb_module
from neuraldem.scenes.fluidized_bed.surrogate.datamodule import BedDataModule
from neuraldem.scenes.fluidized_bed.surrogate.module import BedModule

pytestmark = pytest.mark.solver


def _module(dataset: Path, net_overrides: dict | None = None, stability: dict | None = None,
            **dm_kwargs) -> tuple[BedModule, BedDataModule]:
    dm = BedDataModule(str(dataset), "fb_tiny", **({"batch_size": 4} | dm_kwargs))
    module = BedModule(net_config("fb_tiny", **(net_overrides or {})), datamodule=dm,
                                optimizer={"lr": 1e-3}, scheduler={"warmup_steps": 5}, stability=stability)
    return module, dm


def _fit(module: BedModule, dm: BedDataModule, steps: int) -> L.Trainer:
    trainer = L.Trainer(max_steps=steps, accelerator="cpu", logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, limit_val_batches=0)
    trainer.fit(module, datamodule=dm)
    return trainer


def test_tiny_model_learns_and_checkpoint_round_trips(fb_tiny_dataset: Path, tmp_path: Path):
    torch.manual_seed(0)
    module, dm = _module(fb_tiny_dataset)
    assert module.net.n_scalars == 1 and module.metadata["kind"] == "fluidized_bed"
    batch = next(iter(dm.test_dataloader()))  # held-out velocity, never trained on
    module.eval()
    with torch.no_grad():
        before = module.losses(batch)
    module.train()
    trainer = _fit(module, dm, 40)
    module.eval()
    with torch.no_grad():
        after = module.losses(batch)
    assert after["loss"] < 0.8 * before["loss"], (before, after)
    assert after["loss"] == pytest.approx(sum(after[b] for b in ("particles", "fluid", "mixing")))
    path = tmp_path / "fb.ckpt"
    trainer.save_checkpoint(path)
    back = BedModule.load_from_checkpoint(path).eval()
    assert back.metadata == module.metadata
    assert back.metadata["train_velocities"] == [pytest.approx(1.228531)]
    with torch.no_grad():
        torch.testing.assert_close(back.losses(batch)["loss"], after["loss"])
    # a checkpoint written before the running one-step error existed still loads
    raw = torch.load(path, weights_only=False)
    for key in [k for k in raw["state_dict"] if k.startswith("step_error_")]:
        del raw["state_dict"][key]
    torch.save(raw, tmp_path / "old.ckpt")
    old = BedModule.load_from_checkpoint(tmp_path / "old.ckpt")
    assert int(old.step_error_count) == 0 and not old.step_error_fluid.any()


def test_grid_only_model_trains_and_rolls_forward(fb_tiny_dataset: Path):
    from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import advance

    torch.manual_seed(0)
    module, dm = _module(fb_tiny_dataset, {"particle_branch": False}, push_forward_steps=2,
                         stability={"unroll": [0.0, 1.0]})
    _fit(module, dm, 3)  # the unroll goes through the grid-only rollout step
    batch = next(iter(dm.test_dataloader()))
    with torch.no_grad():
        losses = module.losses(batch)
        nxt = advance(module.net, module.inputs(batch), module.norm, n_particles=50)
    assert set(losses) == {"fluid", "mixing", "loss"} and losses["loss"] == losses["fluid"] + losses["mixing"]
    assert nxt.particle_pos.shape == (batch["scalars"].shape[0], 50, 3) and not nxt.particle_features.any()


def test_residual_model_adds_scaled_changes_to_its_input(fb_tiny_dataset: Path, tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch):
    from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import advance, grid_cells

    torch.manual_seed(0)
    dm = BedDataModule(str(fb_tiny_dataset), "fb_tiny", batch_size=4, push_forward_steps=2)
    module = BedModule(net_config("fb_tiny"), datamodule=dm, residual=True,
                                stability={"unroll": [0.0, 1.0]})
    trainer = _fit(module, dm, 3)  # trains, unrolled through the residual step
    batch = next(iter(dm.test_dataloader()))
    x = module.inputs(batch)
    scales = module.step_scales
    assert scales["fluid"].shape == (4,) and scales["mixing"].shape == (1,)
    real_decode = module.net.decode

    def constant_change(tokens, cond, query_pos, chunk_size=None):  # every grid output = 1 scaled step
        out = real_decode(tokens, cond, query_pos, chunk_size)
        return {k: torch.ones_like(v) if k != "particles" else v for k, v in out.items()}

    monkeypatch.setattr(module.net, "decode", constant_change)
    with torch.no_grad():
        nxt = advance(module.net, x, module.norm, n_particles=30, step_scales=scales)
        losses = module.losses(batch)
    torch.testing.assert_close(grid_cells(nxt.grid), grid_cells(x.grid) + scales["fluid"])
    torch.testing.assert_close(grid_cells(nxt.mixing_grid), grid_cells(x.mixing_grid) + scales["mixing"])
    change = (batch["target_fluid"][:, 0] - grid_cells(x.grid)) / scales["fluid"]
    torch.testing.assert_close(losses["fluid"], (1 - change).square().mean())
    monkeypatch.undo()
    path = tmp_path / "residual.ckpt"
    trainer.save_checkpoint(path)
    back = BedModule.load_from_checkpoint(path)
    assert back.residual and torch.equal(back.step_scales["fluid"], scales["fluid"])
    with pytest.raises(ConfigError, match="model.residual"):
        BedModule(net_config("fb_tiny"), datamodule=dm, residual="yes")


@pytest.mark.parametrize("unroll,loss_on,steps", [([0.0, 0.0, 1.0], "every", 3), ([0.0, 0.0, 1.0], "last", 3),
                                                  ([1.0], "every", 1)])
def test_training_unrolls_the_drawn_steps_and_scores_them(fb_tiny_dataset: Path, monkeypatch: pytest.MonkeyPatch,
                                                          unroll: list[float], loss_on: str, steps: int):
    if loss_on == "last":  # refused: it never trains the one-step map from data
        with pytest.raises(ConfigError, match="never trains the one-step map"):
            _module(fb_tiny_dataset, stability={"unroll": unroll, "loss_on": loss_on}, push_forward_steps=3)
        return
    calls, scored = [], []
    real_next, real_loss = fb_module.next_inputs, BedModule.branch_loss

    def counting_next(net, tokens, cond, fields, x, norm, n_particles, **kwargs):
        calls.append((torch.is_grad_enabled(), n_particles))
        out = real_next(net, tokens, cond, fields, x, norm, n_particles, **kwargs)
        assert out.particle_pos.shape == x.particle_pos.shape and out.grid.shape == x.grid.shape
        assert out.particle_pos.min() >= 0 and out.particle_pos.max() <= 1  # sampled inside the box
        return out

    def counting_loss(self, pred, target, members):
        scored.append(target.shape)
        return real_loss(self, pred, target, members)

    monkeypatch.setattr(fb_module, "next_inputs", counting_next)
    monkeypatch.setattr(BedModule, "branch_loss", counting_loss)
    torch.manual_seed(0)
    module, dm = _module(fb_tiny_dataset, stability={"unroll": unroll, "loss_on": loss_on}, push_forward_steps=3)
    assert module.push_forward_steps == 3 and module.metadata["push_forward_steps"] == 3
    _fit(module, dm, 2)
    assert calls == [(False, 300)] * (2 * (steps - 1))  # each step's input is the last step's detached output
    assert len(scored) == 2 * steps * 3  # every step scored, three branches each
    batch = next(iter(dm.test_dataloader()))
    calls.clear()
    module.losses(batch)  # evaluation: plain next-step
    assert calls == []


def test_volume_projection_is_inside_the_trained_step(fb_tiny_dataset: Path):
    from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import SOLID_FRACTION_CHANNEL, project_volume

    module, dm = _module(fb_tiny_dataset, stability={"conserve_volume": True})
    batch = next(iter(dm.train_dataloader()))
    norm = module.norm
    fluid = torch.randn(4, 90, 4, requires_grad=True)
    out = project_volume(fluid, norm, batch["solid_volume"])
    alpha = out[..., SOLID_FRACTION_CHANNEL] * norm.std["solid_fraction"][0] + norm.mean["solid_fraction"][0]
    assert alpha.min() >= -1e-6
    torch.testing.assert_close(alpha.sum(1).double(), batch["solid_volume"], rtol=1e-5, atol=0)
    (out[..., SOLID_FRACTION_CHANNEL] * torch.linspace(0, 1, 90)).sum().backward()  # the loss sees the projection
    assert fluid.grad is not None and fluid.grad[..., SOLID_FRACTION_CHANNEL].abs().sum() > 0
    torch.testing.assert_close(out[..., :3], fluid[..., :3])  # the other channels pass through
    # a field that piles the solid into a few cells: capped at the densest training value, the rest elsewhere
    dense = fluid.detach().clone()
    dense[..., SOLID_FRACTION_CHANNEL] = -3.0
    dense[:, :5, SOLID_FRACTION_CHANNEL] = 50.0
    alpha = project_volume(dense, norm, batch["solid_volume"])[..., SOLID_FRACTION_CHANNEL] \
        * norm.std["solid_fraction"][0] + norm.mean["solid_fraction"][0]
    assert alpha.max() <= norm.solid_fraction_max + 1e-6 and alpha.min() >= -1e-6
    torch.testing.assert_close(alpha.sum(1).double(), batch["solid_volume"], rtol=1e-5, atol=0)


def test_auto_noise_follows_the_running_one_step_error(fb_tiny_dataset: Path):
    torch.manual_seed(0)
    module, dm = _module(fb_tiny_dataset, stability={"input_noise": "auto"})
    assert float(module.step_error_fluid.sum()) == 0.0
    _fit(module, dm, 3)
    errors = {k: getattr(module, f"step_error_{k}") for k in ("particles", "fluid", "mixing")}
    assert int(module.step_error_count) == 3
    assert errors["fluid"].shape == (4,) and (errors["fluid"] > 0).all() and (errors["fluid"] <= 1).all()
    x = module.inputs(next(iter(dm.train_dataloader())))
    noisy = module.add_input_noise(x)
    per_channel = (noisy.grid - x.grid).transpose(0, 1).flatten(1).std(dim=1)
    torch.testing.assert_close(per_channel, errors["fluid"], rtol=0.15, atol=0.0)
    fixed, _ = _module(fb_tiny_dataset, stability={"input_noise": 0.0})
    assert fixed.add_input_noise(x) is x


def test_config_that_cannot_fit_the_data(fb_tiny_dataset: Path):
    with pytest.raises(ConfigError, match=r"model\.net\.patch_size=\[2, 1, 2\] is invalid: the dataset's grid has "
                                          r"\[6, 1, 15\] cells.*\[1, 3, 5, 15\]"):
        _module(fb_tiny_dataset, {"patch_size": [2, 1, 2]})
    with pytest.raises(ConfigError, match=r"model\.net\.n_supernodes=400 is invalid: a sample holds 300 particles"):
        _module(fb_tiny_dataset, {"n_supernodes": 400})
    with pytest.raises(ConfigError, match=r"n_supernodes=32 is invalid: a sample holds 20 particles"):
        _module(fb_tiny_dataset, {"n_supernodes": 32}, particles_per_sample=20)


def test_bad_optimisation_values(fb_tiny_dataset: Path):
    dm = BedDataModule(str(fb_tiny_dataset), "fb_tiny")
    with pytest.raises(ConfigError, match=r"model\.optimizer\.lr=-1"):
        BedModule(net_config("fb_tiny"), datamodule=dm, optimizer={"lr": -1})
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['warmup'\] in model\.scheduler"):
        BedModule(net_config("fb_tiny"), datamodule=dm, scheduler={"warmup": 3})
    with pytest.raises(ConfigError, match=r"model\.loss_weights key='pressure' is invalid"):
        BedModule(net_config("fb_tiny"), datamodule=dm, loss_weights={"pressure": 1.0})
    with pytest.raises(ConfigError, match=r"model\.optimizer\.betas=\[0\.9\] is invalid: must be a pair"):
        BedModule(net_config("fb_tiny"), datamodule=dm, optimizer={"betas": [0.9]})


def test_flux_consistency_adds_the_continuity_loss(fb_tiny_dataset: Path):
    """Off, no continuity term; on, the total is the branch losses plus the weight times the mean square of the
    continuity residual of the (projected) step, and its gradient reaches the net."""
    from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import (
        apply_stability,
        continuity_residual,
        decode_grid,
    )

    stability = {"conserve_volume": True, "mixing": "advect", "advection_flux": "consistent"}
    torch.manual_seed(0)
    off, dm = _module(fb_tiny_dataset, stability=stability, solids_flux=True)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert "continuity" not in off.losses(batch)
    torch.manual_seed(0)
    on, _ = _module(fb_tiny_dataset, stability=stability | {"flux_consistency": 2.0}, solids_flux=True)
    on.load_state_dict(off.state_dict())
    losses = on.losses(batch)
    branches = sum(on.loss_weights[k] * losses[k] for k in on.net.branches)
    torch.testing.assert_close(losses["loss"], branches + 2.0 * losses["continuity"])
    x = on.inputs(batch)
    with torch.no_grad():
        tokens, cond = on.net.latents(x)
        fields = apply_stability(decode_grid(on.net, tokens, cond, x), x, on.norm, on.stability, batch["solid_volume"])
        expected = continuity_residual(x, fields["fluid"], on.norm).square().mean()
    torch.testing.assert_close(losses["continuity"], expected, rtol=1e-4, atol=1e-6)
    assert losses["continuity"] > 0
    losses["continuity"].backward()
    assert sum(p.grad.abs().sum() for p in on.net.parameters() if p.grad is not None) > 0


def test_an_advected_rollout_step_skips_the_mixing_branch_and_changes_nothing(fb_tiny_dataset: Path):
    """With mixing=advect the step replaces the decoded mixing grid by the advected one: the rollout step leaves
    the mixing decoder out (a third of the decoding) and its next state is the one of the full decode, bit for
    bit."""
    from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import (
        advance,
        apply_stability,
        decode_grid,
        next_inputs,
    )

    torch.manual_seed(0)
    module, dm = _module(fb_tiny_dataset, solids_flux=True,
                         stability={"mixing": "advect", "conserve_volume": True, "advection_flux": "consistent"})
    dm.setup()
    module.eval()
    x = module.inputs(next(iter(dm.test_dataloader())))
    calls = []
    for part in (module.net.decoders["mixing"], module.net.encoders["mixing"]):  # the off-branch's ends
        part.register_forward_hook(lambda *args: calls.append(1))
    with torch.no_grad():
        fast = advance(module.net, x, module.norm, n_particles=30, generator=torch.Generator().manual_seed(3),
                       stability=module.stability)
        assert not calls
        tokens, cond = module.net.latents(x)
        full = apply_stability(decode_grid(module.net, tokens, cond, x), x, module.norm, module.stability, None)
        assert calls  # the reference decoded the mixing grid, and threw it away
        ref = next_inputs(module.net, tokens, cond, full, x, module.norm, 30, torch.Generator().manual_seed(3))
    for name in ("grid", "mixing_grid", "particle_pos", "particle_features"):
        torch.testing.assert_close(getattr(fast, name), getattr(ref, name), rtol=0, atol=0)
    assert not torch.equal(ref.mixing_grid, x.mixing_grid)  # the advection moved something
