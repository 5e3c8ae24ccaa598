"""The typed schema of every net's config (`model.net`), checked where a config becomes a net.

A net config is checked here once, as a whole, before the network is built: every key known (a typo is not
silently ignored), every value of the right type and range, and the rules that tie values together (heads
divide the width, the width embeds the coordinates). The messages name the key, the value and the fix. The
nn modules themselves trust their arguments; `build_net` is the one way a config becomes a net (training, the
checkpoint loader, benchmarks and tools all use it).
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from omegaconf import DictConfig, OmegaConf
from torch import nn

from neuraldem.config import checks
from neuraldem.errors import ConfigError
from neuraldem.models.hopper_field import BRANCH_CHANNELS
from neuraldem.models.modules.supernode_pooling import POSITION_MODES


def _check(check: Callable[..., Any], **kw: Any) -> Any:
    """A schema field checked by `check(key, value, **kw)` (one of `neuraldem.config.checks`)."""
    return dataclasses.field(metadata={"check": check, "kw": kw})


def _patch_size(key: str, value: Any) -> list[int]:
    if isinstance(value, str) or not isinstance(value, (list, tuple)) or len(value) not in (2, 3):
        raise ConfigError(f"config value {key}={value!r} is invalid: must be a list of 2 or 3 positive "
                          f"integers (one per grid axis), e.g. {key}=[4,4,4]")
    return [checks.positive_int(f"{key}[{i}]", p) for i, p in enumerate(value)]


def _optional_positive_int(key: str, value: Any) -> int | None:
    return None if value is None else checks.positive_int(key, value)


@dataclass(frozen=True)
class NetSchema:
    """Base of the net schemas: `target` is the class the config builds (its `_target_`)."""

    target: ClassVar[str]

    @classmethod
    def validate(cls, node: Mapping[str, Any], key: str = "model.net") -> NetSchema:
        """The checked config: given values, and the constructor's defaults for the others."""
        given = {k: v for k, v in node.items() if k != "_target_"}
        names = [f.name for f in dataclasses.fields(cls)]
        checks.known_keys(key, given, names)
        defaults = {name: p.default for name, p in inspect.signature(target_class(cls.target)).parameters.items()
                    if p.default is not inspect.Parameter.empty}
        values = {}
        for f in dataclasses.fields(cls):
            if f.name in given:
                values[f.name] = f.metadata["check"](f"{key}.{f.name}", given[f.name], **f.metadata["kw"])
            elif f.name in defaults:
                values[f.name] = defaults[f.name]
            else:
                raise ConfigError(f"{key}.{f.name} is required (set it in conf/model/*.yaml or override "
                                  f"{key}.{f.name}=...)")
        schema = cls(**values)
        schema.check_together(key)
        return schema

    def check_together(self, key: str) -> None:
        """Rules that tie values together (none by default)."""

    def kwargs(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def build(self) -> nn.Module:
        """The net of this checked config (on the current default device, e.g. `torch.device("meta")`)."""
        return target_class(self.target)(**self.kwargs())


@dataclass(frozen=True)
class AttentionNet(NetSchema):
    """What the two transformer nets share: width, heads, conditioning and their rules."""

    n_scalars: int = _check(checks.positive_int)
    dim: int = _check(checks.positive_int)
    num_heads: int = _check(checks.positive_int)
    cond_dim: int = _check(checks.positive_int)
    mlp_ratio: float = _check(checks.positive)

    def check_together(self, key: str) -> None:
        if self.dim % self.num_heads:  # heads split the width
            raise ConfigError(f"config value {key}.num_heads={self.num_heads} is invalid: must divide "
                              f"{key}.dim={self.dim} (override it, e.g. {key}.num_heads=...)")
        if self.dim < 2 * 3:  # the sin-cos embedding of 3 coordinate axes
            raise ConfigError(f"config value {key}.dim={self.dim} is invalid: must be >= 6 to embed 3 "
                              f"coordinate axes (override it, e.g. {key}.dim=...)")


@dataclass(frozen=True)
class HopperFieldNet(AttentionNet):
    """`models.hopper_field.HopperFieldModel`: the hopper's field model (paper sec. 3, Fig. 3)."""

    target: ClassVar[str] = "neuraldem.models.hopper_field.HopperFieldModel"
    branches: list[str] = _check(checks.names, allowed=list(BRANCH_CHANNELS))
    n_latent_tokens: int = _check(checks.positive_int)
    depth: int = _check(checks.positive_int)
    time_coord_scale: float = _check(checks.positive)
    scalar_coord_scale: float = _check(checks.positive)


@dataclass(frozen=True)
class MultiBranchOperatorNet(AttentionNet):
    """`models.multi_branch_operator.MultiBranchOperator`: the fluidized bed's operator (paper sec. 3-4)."""

    target: ClassVar[str] = "neuraldem.models.multi_branch_operator.MultiBranchOperator"
    particle_channels: int = _check(checks.positive_int)
    fluid_channels: int = _check(checks.positive_int)
    mixing_channels: int = _check(checks.positive_int)
    encoder_depth: int = _check(checks.positive_int, allow_zero=True)
    approximator_depth: int = _check(checks.positive_int, allow_zero=True)
    decoder_depth: int = _check(checks.positive_int, allow_zero=True)
    n_supernodes: int = _check(checks.positive_int)
    n_supernodes_eval: int | None = _check(_optional_positive_int)
    radius: float = _check(checks.positive)
    max_neighbours: int = _check(checks.positive_int)
    position_mode: str = _check(checks.one_of, choices=POSITION_MODES)
    patch_size: list[int] = _check(_patch_size)
    particle_branch: bool = _check(checks.boolean)
    noise_dim: int = _check(checks.positive_int, allow_zero=True)
    scalar_coord_scale: float = _check(checks.positive)


@dataclass(frozen=True)
class GnsNet(NetSchema):
    """`models.gns.GraphNetworkSimulator`: the particle-based baseline."""

    target: ClassVar[str] = "neuraldem.models.gns.GraphNetworkSimulator"
    n_scalars: int = _check(checks.positive_int, allow_zero=True)
    history: int = _check(checks.positive_int)
    n_extra_walls: int = _check(checks.positive_int, allow_zero=True)
    radius: float = _check(checks.positive)
    max_neighbours: int = _check(checks.positive_int)
    dim: int = _check(checks.positive_int)
    hidden: int = _check(checks.positive_int)
    mlp_layers: int = _check(checks.positive_int)
    steps: int = _check(checks.positive_int)


SCHEMAS: dict[str, type[NetSchema]] = {s.target: s for s in (HopperFieldNet, MultiBranchOperatorNet, GnsNet)}


def target_class(target: str) -> type[nn.Module]:
    module, _, name = target.rpartition(".")
    return getattr(importlib.import_module(module), name)


def schema_of(node: Mapping[str, Any], key: str = "model.net") -> type[NetSchema]:
    target = node.get("_target_")
    if target not in SCHEMAS:
        raise ConfigError(f"config value {key}._target_={target!r} is invalid: not a neuraldem net; use one of "
                          f"{sorted(SCHEMAS)}")
    return SCHEMAS[target]


def validate_net(node: Mapping[str, Any] | DictConfig, key: str = "model.net") -> NetSchema:
    """The checked net config (ConfigError naming the key, the value and the fix when it is not valid)."""
    if isinstance(node, DictConfig):
        node = OmegaConf.to_container(node, resolve=True)
    if not isinstance(node, Mapping):
        raise ConfigError(f"{key} must be a mapping with a _target_, got {node!r}")
    return schema_of(node, key).validate(node, key)


def build_net(node: Mapping[str, Any] | DictConfig, key: str = "model.net") -> nn.Module:
    """The net a config describes, checked first."""
    return validate_net(node, key).build()
