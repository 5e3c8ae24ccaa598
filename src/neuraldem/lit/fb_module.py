"""FluidizedBedModule: trains a MultiBranchOperator to step a CFD-DEM fluidized bed forward by one dt.

Loss: the sum over branches (particles, fluid, mixing; weights in config) of the mean squared error in model
units (paper sec. 4.3). With push-forward training (`data.datamodule.push_forward_steps` = k > 1) the model
first rolls itself k - 1 steps forward without gradient, exactly as a rollout does (`fb_autoregressive`),
and is trained on the last step against the data at t + k. `residual=true`: the grid branches predict the
change over the step in units of its typical size per channel (the loss is then the squared error of the
change relative to that size, every channel weighted alike); the next state is the input plus the change. The net is built here with as many input
scalars as the data's conditioning list; checkpoints carry the data's metadata (scene, conditioning,
normalisation, velocities seen in training) that rollouts and evaluation check before using a model.
"""

from __future__ import annotations

from typing import Any

import lightning as L
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from neuraldem.config import checks
from neuraldem.data.fb_datamodule import FluidizedBedDataModule
from neuraldem.data.fb_normalization import FbNormalizer
from neuraldem.errors import ConfigError
from neuraldem.lit.fb_autoregressive import advance, grid_cells, grid_queries, grid_step_scales
from neuraldem.lit.module_setup import loss_weight_settings, net_config_and_metadata
from neuraldem.lit.optim import lion_warmup_cosine, optimizer_settings
from neuraldem.models.modules.patch_embedding import check_patch_size
from neuraldem.models.multi_branch_operator import BRANCHES, OperatorInputs


class FluidizedBedModule(L.LightningModule):
    def __init__(self, net: DictConfig | dict, datamodule: FluidizedBedDataModule | None = None,
                 optimizer: DictConfig | dict | None = None, scheduler: DictConfig | dict | None = None,
                 loss_weights: DictConfig | dict | None = None, chunk_size: int | None = None,
                 metadata: dict[str, Any] | None = None, residual: bool = False):
        super().__init__()
        net_cfg, metadata = net_config_and_metadata("FluidizedBedModule", net, datamodule, metadata)
        self.metadata = metadata
        self.norm = FbNormalizer.from_dict(metadata["normalizer"])
        check_fits_data(net_cfg, self.norm, metadata.get("particles_per_sample"))
        opt, sched = optimizer_settings(optimizer, scheduler)
        weights = loss_weight_settings(loss_weights, BRANCHES)
        if chunk_size is not None:
            checks.positive_int("model.chunk_size", chunk_size)
        self.opt_cfg, self.sched_cfg, self.loss_weights = opt, sched, weights
        self.chunk_size = chunk_size
        self.push_forward_steps = int(metadata.get("push_forward_steps", 1))
        self.residual = checks.boolean("model.residual", residual)
        self.step_scales = grid_step_scales(self.norm) if self.residual else None
        self.save_hyperparameters({"net": OmegaConf.to_container(net_cfg), "optimizer": opt, "scheduler": sched,
                                   "loss_weights": weights, "chunk_size": chunk_size, "metadata": metadata,
                                   "residual": self.residual})
        self.net = instantiate(net_cfg)

    @staticmethod
    def inputs(batch: dict[str, torch.Tensor]) -> OperatorInputs:
        return OperatorInputs(particle_pos=batch["particle_pos"], particle_features=batch["particle_features"],
                              grid=batch["grid"], mixing_grid=batch["mixing_grid"], scalars=batch["scalars"])

    def losses(self, batch: dict[str, torch.Tensor], push_forward_steps: int = 1) -> dict[str, torch.Tensor]:
        """Per-branch MSE (model units) of the prediction at t + k against the batch's targets."""
        x = self.inputs(batch)
        if push_forward_steps > 1:
            with torch.no_grad():
                for _ in range(push_forward_steps - 1):
                    x = advance(self.net, x, self.norm, n_particles=x.particle_pos.shape[1],
                                step_scales=self.step_scales)
        cells = grid_queries(x)
        x.query_pos = {"particles": batch["target_pos"], "fluid": cells, "mixing": cells}
        if not self.net.particle_branch:  # a grid-only model: nothing to decode at the particles
            x.query_pos = {"fluid": cells, "mixing": cells}
        out = self.net(x)
        targets = {name: batch[f"target_{name}"] for name in self.net.branches}
        if self.residual:  # the grid outputs are scaled changes: compare them with the scaled true change
            for name, grid in (("fluid", x.grid), ("mixing", x.mixing_grid)):
                targets[name] = (targets[name] - grid_cells(grid)) / self.step_scales[name].to(grid.device)
        losses = {name: (out[name] - targets[name]).square().mean() for name in self.net.branches}
        losses["loss"] = sum(self.loss_weights[k] * losses[k] for k in self.net.branches)
        return losses

    def _step(self, batch: dict[str, torch.Tensor], stage: str) -> torch.Tensor:
        losses = self.losses(batch, self.push_forward_steps if stage == "train" else 1)
        bs = batch["scalars"].shape[0]
        train = stage == "train"
        self.log(f"{stage}/loss", losses["loss"], prog_bar=True, batch_size=bs, on_step=train, on_epoch=not train)
        self.log_dict({f"{stage}/{k}": v for k, v in losses.items() if k != "loss"}, batch_size=bs,
                      on_step=train, on_epoch=not train)
        return losses["loss"]

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        return self._step(batch, "train")

    def validation_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> None:
        self._step(batch, "val")

    def test_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> None:
        self._step(batch, "test")

    def configure_optimizers(self) -> dict[str, Any]:
        return lion_warmup_cosine(self.parameters(), self.opt_cfg, self.sched_cfg, self.trainer.max_steps)


def check_fits_data(net_cfg: DictConfig, norm: FbNormalizer, particles_per_sample: int | None) -> None:
    """The patches must tile the data's grid and the supernodes fit in a sample: say so before training."""
    patch = check_patch_size(list(net_cfg.get("patch_size", [2, 1, 2])))
    shape = tuple(norm.grid_shape)
    if len(patch) != len(shape) or any(g % p for g, p in zip(shape, patch)):
        divisors = [[d for d in range(1, g + 1) if g % d == 0] for g in shape]
        raise ConfigError(f"config value model.net.patch_size={list(patch)} is invalid: the dataset's grid has "
                          f"{list(shape)} cells, so each patch size must divide its axis (divisors: {divisors}) "
                          "(override it, e.g. model.net.patch_size=[...])")
    n = particles_per_sample or norm.n_particles
    for key in ("n_supernodes", "n_supernodes_eval"):
        value = net_cfg.get(key)
        if value is not None and value > n:
            raise ConfigError(f"config value model.net.{key}={value} is invalid: a sample holds {n} particles "
                              f"(override it, e.g. model.net.{key}={n})")
