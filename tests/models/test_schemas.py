"""The net schemas: every shipped model config passes, a bad value names its key and the fix, and the nn
modules themselves no longer read config."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from neuraldem.errors import ConfigError
from neuraldem.models.gns import GraphNetworkSimulator
from neuraldem.models.multi_branch_operator import MultiBranchOperator
from neuraldem.models.registry import model_config_names, net_config
from neuraldem.models.schemas import (
    SCHEMAS,
    GnsNet,
    HopperFieldNet,
    MultiBranchOperatorNet,
    build_net,
    validate_net,
)

MODELS = Path(__file__).resolve().parents[2] / "src" / "neuraldem" / "models"


@pytest.mark.parametrize("name", model_config_names())
def test_every_shipped_model_config_passes(name: str):
    schema = validate_net(net_config(name))
    assert type(schema) in (HopperFieldNet, MultiBranchOperatorNet, GnsNet)


def test_unset_values_take_the_constructor_defaults():
    s = validate_net({"_target_": MultiBranchOperatorNet.target})
    assert s.n_supernodes == 256 and s.patch_size == (2, 1, 2) and s.n_supernodes_eval is None
    with pytest.raises(ConfigError, match=r"model.net.n_scalars is required"):
        validate_net({"_target_": HopperFieldNet.target})  # HopperFieldModel has no default for it


@pytest.mark.parametrize(("override", "message"), [
    ({"dim": 0}, r"model.net.dim=0 is invalid: must be a positive integer"),
    ({"n_scalars": 0}, r"model.net.n_scalars=0 is invalid"),
    ({"mlp_ratio": 0}, r"model.net.mlp_ratio=0 is invalid: must be > 0"),
    ({"dim": 96.5}, r"model.net.dim=96.5 is invalid: must be an integer"),
    ({"num_heads": 5}, r"model.net.num_heads=5 is invalid: must divide model.net.dim=96"),
    ({"dim": 4, "num_heads": 1}, r"model.net.dim=4 is invalid: must be >= 6"),
    ({"radius": -0.1}, r"model.net.radius=-0.1 is invalid"),
    ({"position_mode": "sideways"}, r"model.net.position_mode='sideways' is invalid: must be one of"),
    ({"patch_size": [2, 0, 2]}, r"model.net.patch_size\[1\]=0 is invalid"),
    ({"patch_size": 2}, r"model.net.patch_size=2 is invalid: must be a list of 2 or 3"),
    ({"particle_branch": "yes"}, r"model.net.particle_branch='yes' is invalid: must be true or false"),
    ({"encoder_depth": -1}, r"model.net.encoder_depth=-1 is invalid: must be >= 0"),
    ({"n_supernode": 64}, r"unknown key\(s\) \['n_supernode'\] in model.net"),
])
def test_a_bad_value_names_its_key_value_and_fix(override: dict, message: str):
    node = OmegaConf.merge(net_config("fb_small"), override)
    with pytest.raises(ConfigError, match=message):
        validate_net(node)


def test_hopper_branches_and_gns_values_are_checked():
    with pytest.raises(ConfigError, match=r"model.net.branches=.*unknown name\(s\) \['velocity'\]"):
        validate_net(OmegaConf.merge(net_config("hopper_small"), {"branches": ["occupancy", "velocity"]}))
    with pytest.raises(ConfigError, match=r"model.net.steps=0 is invalid"):
        validate_net(OmegaConf.merge(net_config("gns_small"), {"steps": 0}))
    assert validate_net(OmegaConf.merge(net_config("gns_small"), {"n_scalars": 0})).n_scalars == 0


def test_not_a_net_is_refused():
    with pytest.raises(ConfigError, match=r"model.net._target_='torch.nn.Linear' is invalid: not a neuraldem net"):
        validate_net({"_target_": "torch.nn.Linear", "in_features": 2})
    with pytest.raises(ConfigError, match=r"model.net._target_=None"):
        validate_net({"dim": 4})


def test_build_net_gives_the_same_weights_as_the_class():
    node = OmegaConf.merge(net_config("fb_tiny"), {"n_scalars": 1})
    torch.manual_seed(0)
    built = build_net(node)
    torch.manual_seed(0)
    direct = MultiBranchOperator(**{k: v for k, v in OmegaConf.to_container(node).items() if k != "_target_"})
    assert isinstance(built, MultiBranchOperator)
    a, b = built.state_dict(), direct.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    gns = build_net(OmegaConf.merge(net_config("gns_tiny"), {"n_scalars": 2}))
    assert isinstance(gns, GraphNetworkSimulator) and gns.n_scalars == 2


def test_every_net_class_has_a_schema_that_covers_its_arguments():
    import inspect

    from neuraldem.models.registry import NETS

    for cls in NETS.values():
        schema = SCHEMAS[f"{cls.__module__}.{cls.__qualname__}"]
        arguments = set(inspect.signature(cls).parameters)
        assert arguments == {f for f in schema.__dataclass_fields__ if f != "target"}, cls


def test_nn_modules_do_not_import_config():
    """Only the schemas read config (and the scalar baselines, not nets, their `data.conditioning`); the nn
    modules trust their arguments."""
    readers = []
    for path in sorted(MODELS.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            if any(n.startswith("neuraldem.config") for n in names):
                readers.append(path.relative_to(MODELS).as_posix())
    assert sorted(set(readers)) == ["scalar_baselines.py", "schemas.py"], readers
