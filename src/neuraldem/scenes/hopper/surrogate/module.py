"""HopperModule: trains a HopperFieldModel on occupancy, transport and residence (losses summed).

The net is built here from its config, with as many input scalars as the data's conditioning list, so
conditioning ablations need no change to the model config. Checkpoints carry the data's metadata
(scene, conditioning, normalisation) that evaluation checks before using a model.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from omegaconf import DictConfig, OmegaConf

from neuraldem.config import checks
from neuraldem.lit.base import SurrogateModule
from neuraldem.lit.module_setup import loss_weight_settings, net_config_and_metadata
from neuraldem.lit.optim import optimizer_settings
from neuraldem.models.schemas import build_net
from neuraldem.scenes.hopper.surrogate.datamodule import HopperDataModule

LOSSES = ("occupancy", "transport", "residence")


class HopperModule(SurrogateModule):
    def __init__(self, net: DictConfig | dict, datamodule: HopperDataModule | None = None,
                 optimizer: DictConfig | dict | None = None, scheduler: DictConfig | dict | None = None,
                 loss_weights: DictConfig | dict | None = None, chunk_size: int | None = None,
                 metadata: dict[str, Any] | None = None):
        super().__init__()
        net_cfg, metadata = net_config_and_metadata("HopperModule", net, datamodule, metadata)
        self.metadata = metadata
        opt, sched = optimizer_settings(optimizer, scheduler)
        weights = loss_weight_settings(loss_weights, LOSSES)
        self.opt_cfg, self.sched_cfg, self.loss_weights = opt, sched, weights
        self.chunk_size = None if chunk_size is None else checks.positive_int("model.chunk_size", chunk_size)
        self.save_hyperparameters({"net": OmegaConf.to_container(net_cfg), "optimizer": opt, "scheduler": sched,
                                   "loss_weights": weights, "chunk_size": chunk_size, "metadata": metadata})
        self.net = build_net(net_cfg)

    def forward(self, scalars: torch.Tensor, query_pos: Any) -> dict[str, torch.Tensor]:
        return self.net(scalars, query_pos, chunk_size=self.chunk_size)

    def losses(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        out = self.net(batch["scalars"], {"occupancy": batch["occupancy_pos"],
                                          "transport": batch["particle_pos"], "residence": batch["particle_pos"]})
        mask = batch["particle_mask"].float()
        # masked means: the count is shared between data-parallel processes (SurrogateModule.shared_count)
        n = self.shared_count(mask.sum()).clamp(min=1.0)
        # refill data: material inserted after the reference time has no transport target
        tmask = batch["transport_mask"].float() if "transport_mask" in batch else mask
        losses = {
            "occupancy": F.binary_cross_entropy_with_logits(out["occupancy"][..., 0], batch["occupancy"]),
            "transport": (((out["transport"] - batch["transport"]) ** 2).mean(-1) * tmask).sum()
            / self.shared_count(tmask.sum()).clamp(min=1.0),
            "residence": (((out["residence"][..., 0] - batch["residence"]) ** 2) * mask).sum() / n,
        }
        with torch.no_grad():
            pred = out["occupancy"][..., 0] > 0
            losses["occupancy_accuracy"] = (pred == (batch["occupancy"] > 0.5)).float().mean()
        losses["loss"] = sum(self.loss_weights[k] * losses[k] for k in LOSSES)
        return losses

    def stage_losses(self, batch: dict[str, torch.Tensor], stage: str) -> dict[str, torch.Tensor]:
        return self.losses(batch)
