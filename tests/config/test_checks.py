"""Config value checks: accept good values, reject bad ones with the key and the requirement."""

from __future__ import annotations

import pytest

from neuraldem.config import checks
from neuraldem.errors import ConfigError


@pytest.mark.parametrize("value", [-1, 0, 1.5, "3", True, None])
def test_positive_int_rejects(value):
    with pytest.raises(ConfigError, match=r"data\.batch_size="):
        checks.positive_int("data.batch_size", value)


def test_positive_int_accepts():
    assert checks.positive_int("x", 3) == 3
    assert checks.positive_int("x", 0, allow_zero=True) == 0


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -0.1, 1.1, "a"])
def test_fraction_rejects(value):
    with pytest.raises(ConfigError, match="invalid"):
        checks.fraction("splits.val", value)


def test_boolean_takes_only_true_or_false():
    assert checks.boolean("x", True) is True and checks.boolean("x", False) is False
    for value in (1, 0, "true", None):
        with pytest.raises(ConfigError, match="must be true or false"):
            checks.boolean("rollout.flag", value)


def test_interval_and_names():
    assert checks.interval("r", [0, 60]) == (0.0, 60.0)
    with pytest.raises(ConfigError, match="lo <= hi"):
        checks.interval("r", [60, 0])
    assert checks.names("c", ["t", "alpha"], allowed=["t", "alpha", "mu_s"]) == ["t", "alpha"]
    with pytest.raises(ConfigError, match="unknown name"):
        checks.names("c", ["t", "beta"], allowed=["t", "alpha"])
    with pytest.raises(ConfigError, match="duplicate"):
        checks.names("c", ["t", "t"])


def test_required_keys_name_themselves_and_an_example():
    from omegaconf import OmegaConf

    cfg = OmegaConf.create({"ckpt": "???", "velocity": 1.5})
    with pytest.raises(ConfigError, match=r"ckpt is required: neuraldem evaluate ckpt=X"):
        checks.required(cfg, "evaluate", {"ckpt": "ckpt=X", "velocity": "velocity=1.6"})
    checks.required(OmegaConf.create({"ckpt": "a.ckpt"}), "evaluate", {"ckpt": "ckpt=X"})  # present: no error
    with pytest.raises(ConfigError, match=r"ckpt is required: neuraldem evaluate rollout ckpt=X"):
        checks.required(cfg, "rollout", {"ckpt": "ckpt=X"})


def test_is_multiple_tolerates_float_rounding_only():
    assert checks.is_multiple(0.01, 1e-4) and checks.is_multiple(0.2, 0.01) and checks.is_multiple(0.3, 0.1)
    assert not checks.is_multiple(0.00015, 1e-4) and not checks.is_multiple(0.015, 0.01)
