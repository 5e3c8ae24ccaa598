"""BedModule: trains a MultiBranchOperator to step a CFD-DEM fluidized bed forward by one dt.

Loss: the sum over branches (particles, fluid, mixing; weights in config) of the mean squared error in model
units (paper sec. 4.3), or of the fair CRPS over `stability.ensemble` >= 2 members of a stochastic net. Each
training batch unrolls k steps (k drawn from `stability.unroll`) from a data snapshot, exactly as a rollout
steps (`scenes.fluidized_bed.autoregressive`, with the volume projection and mixing advection when enabled), the
inputs of each step detached from the previous one's graph, and is scored on every step (or the last,
`stability.loss_on`) against the data at t + 1 .. t + k (`neuraldem.scenes.fluidized_bed.surrogate.options`).
`residual=true`:
the grid branches predict the change over the step in units of its typical size per channel (the loss is then the
squared error of the change relative to that size, every channel weighted alike); the next state is the input plus the
change. The net is built here with as many input scalars as the data's conditioning list; checkpoints carry the data's
metadata (scene, conditioning, normalisation, velocities seen in training) that rollouts and evaluation check
before using a model.

Training draws (the unroll length, input noise, supernodes, latent noise, the particles re-sampled between unrolled
steps) come from `training_draws()`, per row of the global batch: the same with one process or several, and
in a resumed run (`neuraldem.lit.distributed`). Outside training steps they come from torch's global RNG.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf

from neuraldem.config import checks
from neuraldem.errors import ConfigError
from neuraldem.lit.base import SurrogateModule
from neuraldem.lit.distributed import TrainingDraws
from neuraldem.lit.module_setup import loss_weight_settings, net_config_and_metadata
from neuraldem.lit.optim import optimizer_settings, plain
from neuraldem.models.multi_branch_operator import BRANCHES, OperatorInputs
from neuraldem.models.schemas import MultiBranchOperatorNet, validate_net
from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import (
    apply_stability,
    continuity_residual,
    decode_grid,
    grid_cells,
    grid_step_scales,
    next_inputs,
    perturb_inputs,
    solid_volume,
)
from neuraldem.scenes.fluidized_bed.surrogate.datamodule import BedDataModule
from neuraldem.scenes.fluidized_bed.surrogate.normalization import BedNormalizer
from neuraldem.scenes.fluidized_bed.surrogate.options import BedStability, training_stability

OLD_DATAMODULE_NAME = "FluidizedBedDataModule"  # Lightning keys a data module's state by its class name

class BedModule(SurrogateModule):
    # set from the dataset, not model.net: the grid's channel count (4, or 7 with the solids flux of experiment=fb);
    # a resumed run is not refused for them (`neuraldem.train.check_resume_checkpoint`)
    DATA_DERIVED_NET_KEYS = frozenset({"fluid_channels"})

    def __init__(self, net: DictConfig | dict, datamodule: BedDataModule | None = None,
                 optimizer: DictConfig | dict | None = None, scheduler: DictConfig | dict | None = None,
                 loss_weights: DictConfig | dict | None = None, chunk_size: int | None = None,
                 metadata: dict[str, Any] | None = None, residual: bool = False,
                 stability: DictConfig | dict | None = None):
        super().__init__()
        net_cfg, metadata = net_config_and_metadata("BedModule", net, datamodule, metadata)
        net_cfg.fluid_channels = int(metadata.get("grid_channels", net_cfg.get("fluid_channels", 4)))
        self.metadata = metadata
        self.norm = BedNormalizer.from_dict(metadata["normalizer"])
        net_schema = validate_net(net_cfg)  # checked once: the fit to the data below, then the build
        if not isinstance(net_schema, MultiBranchOperatorNet):
            raise ConfigError(f"config value model.net._target_={net_schema.target!r} is invalid: the fluidized "
                              f"bed's model is {MultiBranchOperatorNet.target}")
        check_fits_data(net_schema, self.norm, metadata.get("particles_per_sample"))
        opt, sched = optimizer_settings(optimizer, scheduler)
        weights = loss_weight_settings(loss_weights, BRANCHES)
        if chunk_size is not None:
            checks.positive_int("model.chunk_size", chunk_size)
        self.opt_cfg, self.sched_cfg, self.loss_weights = opt, sched, weights
        self.chunk_size = chunk_size
        self.push_forward_steps = int(metadata.get("push_forward_steps", 1))
        self.stability = BedStability.from_config(plain(stability))
        self.stability.check_fits(self.push_forward_steps, bool(metadata.get("solids_flux", False)),
                                  int(net_cfg.get("noise_dim", 0) or 0))
        self.residual = checks.boolean("model.residual", residual)
        self.step_scales = grid_step_scales(self.norm) if self.residual else None
        self.save_hyperparameters({"net": OmegaConf.to_container(net_cfg), "optimizer": opt, "scheduler": sched,
                                   "loss_weights": weights, "chunk_size": chunk_size, "metadata": metadata,
                                   "residual": self.residual, "stability": self.stability.to_dict()})
        self.net = net_schema.build()
        # running one-step RMS error per input channel (model units): the noise of input_noise=auto
        channels = {"particles": self.net.channels["particles"], "fluid": net_cfg.fluid_channels, "mixing": 1}
        for name, c in channels.items():
            self.register_buffer(f"step_error_{name}", torch.zeros(c), persistent=True)
        self.register_buffer("step_error_count", torch.zeros((), dtype=torch.long), persistent=True)

    @staticmethod
    def config_kwargs(cfg: DictConfig) -> dict[str, Any]:
        """Constructor arguments from the whole training config besides `model` (`neuraldem.train`): the stability
        options with the `rollout` group's given ones in place (`options.training_stability`)."""
        return {"stability": training_stability(plain(cfg.model.get("stability")), plain(cfg.get("rollout")))}

    @staticmethod
    def inputs(batch: dict[str, torch.Tensor]) -> OperatorInputs:
        return OperatorInputs(particle_pos=batch["particle_pos"], particle_features=batch["particle_features"],
                              grid=batch["grid"], mixing_grid=batch["mixing_grid"], scalars=batch["scalars"])

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """Checkpoints from before the running one-step error existed load with it at zero; the data module's
        place in its epoch, stored under its class name, is found under the name it had before (0.6)."""
        if OLD_DATAMODULE_NAME in checkpoint and "BedDataModule" not in checkpoint:
            checkpoint["BedDataModule"] = checkpoint.pop(OLD_DATAMODULE_NAME)
        state = checkpoint.get("state_dict", {})
        for name, buf in self.named_buffers():
            if name.startswith("step_error_") and name not in state:
                state[name] = torch.zeros_like(buf)

    # ---- training-time input noise
    def noise_std(self) -> dict[str, torch.Tensor | float]:
        if self.stability.input_noise == "auto":
            return {name: getattr(self, f"step_error_{name}") for name in ("particles", "fluid", "mixing")}
        return dict.fromkeys(("particles", "fluid", "mixing"), float(self.stability.input_noise))

    def add_input_noise(self, x: OperatorInputs, draws: TrainingDraws | None = None) -> OperatorInputs:
        std = self.noise_std()
        if all(not torch.is_tensor(v) and v == 0.0 for v in std.values()):
            return x

        def draw(name: str, t: torch.Tensor) -> torch.Tensor:
            if draws is None:
                return torch.randn_like(t)
            return draws.rows(f"input_noise/{name}", t.shape[0], t.shape[1:], dtype=t.dtype)

        return perturb_inputs(x, std, draw)

    @torch.no_grad()
    def update_step_error(self, out: dict[str, torch.Tensor], targets: dict[str, torch.Tensor]) -> None:
        rate = self.stability.noise_ema if int(self.step_error_count) > 0 else 0.0
        for name in self.net.branches:
            # the mean square over the global batch (every process holds as many rows), then its root
            ms = (out[name] - targets[name]).float().square().mean(dim=tuple(range(out[name].ndim - 1)))
            rms = self.mean_over_ranks(ms).sqrt()
            buf = getattr(self, f"step_error_{name}")
            buf.mul_(rate).add_((1.0 - rate) * rms.clamp(max=1.0))
        self.step_error_count += 1

    # ---- losses
    def draw_unroll(self, draws: TrainingDraws | None = None) -> int:
        probs = torch.tensor(self.stability.unroll, dtype=torch.float64)
        generator = None if draws is None else draws.batch_generator("unroll")
        return int(torch.multinomial(probs, 1, generator=generator).item()) + 1

    def keyed_inputs(self, x: OperatorInputs, draws: TrainingDraws, k: int, members: int) -> OperatorInputs:
        """Step k's supernodes (and latent noise of a stochastic net) from the batch's training draws, rather
        than drawn inside the net from the global RNG."""
        rows = x.scalars.shape[0] // members
        if self.net.particle_branch:
            pick = draws.rows(f"supernodes/{k}", rows, (x.particle_pos.shape[1],), kind="uniform", members=members)
            x = replace(x, supernode_idx=pick.topk(self.net.encoders["particles"].n_supernodes, dim=1).indices)
        if self.net.noise_dim:
            x = replace(x, noise=draws.rows(f"latent_noise/{k}", rows, (self.net.noise_dim,), members=members))
        return x

    def branch_loss(self, pred: torch.Tensor, target: torch.Tensor, members: int) -> torch.Tensor:
        """MSE (one member) or the fair CRPS over `members` stacked along the batch (averaged over elements)."""
        if members == 1:
            return (pred - target).square().mean()
        return fair_crps(pred.reshape(members, -1, *pred.shape[1:]), target.reshape(members, -1,
                                                                                    *target.shape[1:])[0])

    def losses(self, batch: dict[str, torch.Tensor], unroll: int = 1, train: bool = False,
               draws: TrainingDraws | None = None) -> dict[str, torch.Tensor]:
        """Per-branch losses (model units), averaged over the scored steps of a `unroll`-step rollout from the
        batch's snapshot against its targets at t + 1 .. t + unroll; `draws`: the training draws (else torch's
        global RNG)."""
        members = self.stability.ensemble if train else 1
        x = self.inputs(batch)
        volume = batch.get("solid_volume")
        if volume is None:
            volume = solid_volume(x.grid, self.norm)
        if train:
            x = self.add_input_noise(x, draws)
        if members > 1:
            x = repeat_members(x, members)
            volume = volume.repeat(members)
        rows = x.scalars.shape[0] // members
        n_particles = x.particle_pos.shape[1]
        totals: dict[str, torch.Tensor] = {}
        scored = 0
        for k in range(unroll):
            targets = {name: batch[f"target_{name}"][:, k] for name in self.net.branches}
            if members > 1:
                targets = {name: t.repeat(members, *([1] * (t.ndim - 1))) for name, t in targets.items()}
            if draws is not None:
                x = self.keyed_inputs(x, draws, k, members)
            tokens, cond = self.net.latents(x)
            raw = decode_grid(self.net, tokens, cond, x, self.chunk_size, self.step_scales)
            fields = apply_stability(raw, x, self.norm, self.stability, volume)
            # the loss sees the projected solid fraction; the mixing off-branch is trained on its own prediction
            # even when rollouts advect the concentration instead (the same checkpoint can do either)
            out = {"fluid": fields["fluid"], "mixing": raw["mixing"]}
            if self.net.particle_branch:
                pos = batch["target_pos"][:, k]
                pos = pos.repeat(members, 1, 1) if members > 1 else pos
                out["particles"] = self.net.decode(tokens, cond, {"particles": pos}, self.chunk_size)["particles"]
            if self.residual:  # compare scaled changes
                for name, grid in (("fluid", x.grid), ("mixing", x.mixing_grid)):
                    scale = self.step_scales[name].to(grid.device)
                    out[name] = (out[name] - grid_cells(grid)) / scale
                    targets[name] = (targets[name] - grid_cells(grid)) / scale
            if train and k == 0 and not self.residual:
                self.update_step_error(out, targets)
            if self.stability.loss_on == "every" or k == unroll - 1:
                for name in self.net.branches:
                    totals[name] = totals.get(name, 0.0) + self.branch_loss(out[name], targets[name], members)
                if self.stability.flux_consistency > 0:  # the flux must carry the solid it predicts
                    r = continuity_residual(x, fields["fluid"], self.norm)
                    totals["continuity"] = totals.get("continuity", 0.0) + r.square().mean()
                scored += 1
            if k < unroll - 1:  # the next step starts from this one's prediction, without its graph
                with torch.no_grad():
                    generator = None if draws is None else draws.generators(f"positions/{k}", rows, members)
                    x = next_inputs(self.net, tokens, cond, {n: f.detach() for n, f in fields.items()}, x, self.norm,
                                    n_particles, generator=generator, chunk_size=self.chunk_size)
        losses = {name: v / scored for name, v in totals.items()}
        losses["loss"] = sum(self.loss_weights[k] * losses[k] for k in self.net.branches)
        if "continuity" in losses:
            losses["loss"] = losses["loss"] + self.stability.flux_consistency * losses["continuity"]
        return losses

    def stage_losses(self, batch: dict[str, torch.Tensor], stage: str) -> dict[str, torch.Tensor]:
        """Training draws the unroll length per batch; validation and test score the one-step map."""
        if stage != "train":
            return self.losses(batch)
        draws = self.training_draws()
        return self.losses(batch, self.draw_unroll(draws), train=True, draws=draws)


def fair_crps(members: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean over elements of the fair (unbiased) CRPS of an ensemble (M, ...) against `target` (...):
    mean_i |x_i - y| - sum_{i != j} |x_i - x_j| / (2 M (M - 1)). Minimised in expectation when the members
    are draws from the true distribution, so a stochastic model keeps the spread an MSE fit averages away."""
    m = members.shape[0]
    skill = (members - target.unsqueeze(0)).abs().mean(dim=0)
    spread = (members.unsqueeze(0) - members.unsqueeze(1)).abs().sum(dim=(0, 1)) / (2 * m * (m - 1))
    return (skill - spread).mean()


def repeat_members(x: OperatorInputs, members: int) -> OperatorInputs:
    """The batch stacked `members` times (member-major), each copy drawing its own latent noise."""
    def rep(t: torch.Tensor) -> torch.Tensor:
        return t.repeat(members, *([1] * (t.ndim - 1)))

    return replace(x, particle_pos=rep(x.particle_pos), particle_features=rep(x.particle_features), grid=rep(x.grid),
                   mixing_grid=rep(x.mixing_grid), scalars=rep(x.scalars), noise=None, particle_graph=None,
                   supernode_idx=None if x.supernode_idx is None else rep(x.supernode_idx))


def check_fits_data(net: MultiBranchOperatorNet, norm: BedNormalizer, particles_per_sample: int | None) -> None:
    """The patches must tile the data's grid and the supernodes fit in a sample: say so before training."""
    patch = net.patch_size
    shape = tuple(norm.grid_shape)
    if len(patch) != len(shape) or any(g % p for g, p in zip(shape, patch, strict=False)):
        divisors = [[d for d in range(1, g + 1) if g % d == 0] for g in shape]
        raise ConfigError(f"config value model.net.patch_size={list(patch)} is invalid: the dataset's grid has "
                          f"{list(shape)} cells, so each patch size must divide its axis (divisors: {divisors}) "
                          "(override it, e.g. model.net.patch_size=[...])")
    n = particles_per_sample or norm.n_particles
    for key in ("n_supernodes", "n_supernodes_eval"):
        value = getattr(net, key)
        if value is not None and value > n:
            raise ConfigError(f"config value model.net.{key}={value} is invalid: a sample holds {n} particles "
                              f"(override it, e.g. model.net.{key}={n})")
