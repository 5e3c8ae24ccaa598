"""What every LightningModule of ours does before building its net, in one place: take the conditioning
(and everything else a checkpoint must carry) from the data when training, from the checkpoint otherwise, and
check the per-branch loss weights."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from omegaconf import DictConfig, OmegaConf

from neuraldem.config import checks
from neuraldem.lit.optim import plain


def net_config_and_metadata(owner: str, net: DictConfig | dict, datamodule: Any | None,
                            metadata: dict[str, Any] | None) -> tuple[DictConfig, dict[str, Any]]:
    """The net config with as many input scalars as the data's conditioning list, and the metadata (from the
    datamodule when training, as given when loading a checkpoint)."""
    net_cfg = OmegaConf.create(net if not isinstance(net, DictConfig) else OmegaConf.to_container(net))
    if metadata is None:  # training: the data decides what the model is conditioned on
        if datamodule is None:
            raise ValueError(f"{owner} needs a datamodule (training) or metadata (a checkpoint)")
        datamodule.prepare_manifest()
        datamodule.setup("fit")
        metadata = datamodule.checkpoint_metadata()
    net_cfg.n_scalars = len(metadata["conditioning"])
    return net_cfg, metadata


def loss_weight_settings(loss_weights: DictConfig | dict | None, branches: Sequence[str]) -> dict[str, float]:
    """One weight per branch (default 1), unknown branches and negative weights refused."""
    weights = dict.fromkeys(branches, 1.0) | plain(loss_weights)
    for k, v in weights.items():
        checks.one_of("model.loss_weights key", k, list(branches))
        checks.number(f"model.loss_weights.{k}", v, lo=0.0)
    return weights
