"""Registered nets, and building the `net:` of any `conf/model/<name>.yaml` by config name.

Tests, benchmarks and tools use `build_net(name)` to get exactly the network a training run would get.
"""

from __future__ import annotations

from typing import Any

from omegaconf import DictConfig, OmegaConf
from torch import nn

from neuraldem.errors import ConfigError
from neuraldem.models import schemas
from neuraldem.models.gns import GraphNetworkSimulator
from neuraldem.models.hopper_field import HopperFieldModel
from neuraldem.models.multi_branch_operator import MultiBranchOperator
from neuraldem.paths import config_dir

NETS: dict[str, type[nn.Module]] = {
    "hopper_field": HopperFieldModel,
    "multi_branch_operator": MultiBranchOperator,
    "gns": GraphNetworkSimulator,
}
_TARGETS = {f"{cls.__module__}.{cls.__qualname__}": cls for cls in NETS.values()}


def model_config_names() -> list[str]:
    """Names of the model configs (`conf/model/*.yaml`), e.g. "hopper_tiny"."""
    return sorted(path.stem for path in (config_dir() / "model").glob("*.yaml"))


def net_config(name: str, **overrides: Any) -> DictConfig:
    """The `net:` node of `conf/model/<name>.yaml`; `overrides` replace its values (e.g. n_scalars=4)."""
    path = config_dir() / "model" / f"{name}.yaml"
    if not path.is_file():
        raise ConfigError(f"model config {name!r} does not exist ({path}); "
                          f"choose one of {model_config_names()}")
    cfg = OmegaConf.load(path)
    if not isinstance(cfg, DictConfig) or not isinstance(cfg.get("net"), DictConfig):
        raise ConfigError(f"{path} has no `net:` section; add one with a _target_ from {sorted(_TARGETS)}")
    net = OmegaConf.merge(cfg.net, overrides)
    if net.get("_target_") not in _TARGETS:
        raise ConfigError(f"model.net._target_={net.get('_target_')!r} in {path} is not a neuraldem net; "
                          f"use one of {sorted(_TARGETS)}")
    return net


def build_net(name: str, **overrides: Any) -> nn.Module:
    """Instantiate the net of model config `name` (on the current default device, e.g. inside
    `with torch.device("meta"):` to size a model without allocating it)."""
    return schemas.build_net(net_config(name, **overrides))
