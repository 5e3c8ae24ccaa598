"""GnsModule: trains the particle-based baseline (`models.gns.GraphNetworkSimulator`) on one-step targets.

Loss: mean squared error of the standardised acceleration over the particles that have a next position (the
data layer's `mask`). The net is built here with the data's history length, conditioning scalars and
scene walls, so one model config serves both scenes; checkpoints carry the data's metadata (`kind` "gns",
`scene_kind`, normalisation) that rollouts check before using a model.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from neuraldem.errors import ConfigError
from neuraldem.gns.datamodule import GnsDataModule, GnsNormalizer
from neuraldem.lit.base import SurrogateModule
from neuraldem.lit.module_setup import net_config_and_metadata
from neuraldem.lit.optim import optimizer_settings
from neuraldem.models.schemas import build_net

SET_FROM_DATA = {"history": "data.datamodule.history", "n_extra_walls": "the dataset's scene"}


class GnsModule(SurrogateModule):
    def __init__(self, net: DictConfig | dict, datamodule: GnsDataModule | None = None,
                 optimizer: DictConfig | dict | None = None, scheduler: DictConfig | dict | None = None,
                 metadata: dict[str, Any] | None = None):
        super().__init__()
        net_cfg, metadata = net_config_and_metadata("GnsModule", net, datamodule, metadata)
        for key, source in SET_FROM_DATA.items():
            if key in net_cfg and net_cfg[key] is not None and net_cfg[key] != metadata[key]:
                raise ConfigError(f"config value model.net.{key}={net_cfg[key]} is invalid: it is set by {source} "
                                  f"({metadata[key]}); remove it from the model config")
            net_cfg[key] = metadata[key]
        self.metadata = metadata
        self.norm = GnsNormalizer.from_dict(metadata["normalizer"])
        opt, sched = optimizer_settings(optimizer, scheduler)
        self.opt_cfg, self.sched_cfg = opt, sched
        self.save_hyperparameters({"net": OmegaConf.to_container(net_cfg), "optimizer": opt, "scheduler": sched,
                                   "metadata": metadata})
        self.net = build_net(net_cfg)

    def forward(self, batch: Any) -> torch.Tensor:
        """Standardised accelerations (N, 3) of a torch_geometric batch (or one graph's dict of inputs)."""
        get = batch.get if isinstance(batch, dict) else (lambda k: getattr(batch, k, None))
        pos = get("pos")
        graph = get("batch")
        if graph is None:
            graph = torch.zeros(pos.shape[0], dtype=torch.long, device=pos.device)
        return self.net(pos, get("velocities"), get("box_lo"), get("box_hi"), graph, get("scalars"),
                        get("wall_distance"))

    @torch.no_grad()
    def acceleration(self, inputs: dict[str, torch.Tensor]) -> np.ndarray:
        """Physical accelerations [m/s^2] (N, 3) for one graph's inputs (`gns.datamodule.graph_inputs`)."""
        device = next(self.net.parameters()).device
        out = self({k: v.to(device) for k, v in inputs.items()})
        return self.norm.acceleration_back(out.double().cpu().numpy())

    def losses(self, batch: Any) -> dict[str, torch.Tensor]:
        pred = self(batch)
        mask = batch.mask.float()
        err = (pred - batch.y).square().mean(dim=-1)
        return {"loss": (err * mask).sum() / self.shared_count(mask.sum()).clamp(min=1.0)}

    def stage_losses(self, batch: Any, stage: str) -> dict[str, torch.Tensor]:
        return self.losses(batch)

    def batch_size(self, batch: Any) -> int:
        return int(batch.num_graphs)
