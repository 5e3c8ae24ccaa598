"""The refilling hopper's settings and LIGGGHTS input (no solver run here: the real runs are in
tests/scenes/hopper_refill/test_datagen.py)."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from neuraldem.errors import ConfigError
from neuraldem.scenes.hopper.solver import HopperGeometry, HopperScene
from neuraldem.scenes.hopper_refill.solver import RefillSettings, n_intervals, refill_input, refill_region, settled_top
from neuraldem.sim.seeds import prime_seeds
from tests.helpers import REPO


@pytest.fixture(scope="module")
def scene() -> HopperScene:
    base = OmegaConf.load(REPO / "conf/data/hopper_small.yaml").scene
    tiny = OmegaConf.load(REPO / "conf/data/hopper_refill_tiny.yaml").scene
    return HopperScene.from_config(OmegaConf.merge(base, tiny), "data.scene")


@pytest.mark.parametrize(("values", "message"), [
    ({"interval": 0.0}, r"data.refill.interval=0.0 is invalid: must be > 0"),
    ({"level_band": [0.9, 0.95]}, r"data.refill.level_band=\[0.9, 0.95\] is invalid: needs 0 < lo < 1 <= hi"),
    ({"level_band": [0.9]}, r"data.refill.level_band=\[0.9\] is invalid: must be a pair"),
    ({"region_height_d": 1.0}, r"data.refill.region_height_d=1.0 is invalid: must be >= 2.0"),
    ({"rate": 3}, r"unknown key\(s\) \['rate'\] in data.refill"),
])
def test_bad_refill_values_name_the_key(values, message):
    with pytest.raises(ConfigError, match=message):
        RefillSettings.from_config(values, "data.refill")


def test_interval_must_fit_the_scene(scene):
    with pytest.raises(ConfigError, match=r"data.refill.interval=0.00015 is invalid: must be a multiple of "
                                          r"data.scene.material.dt"):
        RefillSettings(interval=0.00015).validate("data.refill", scene)
    with pytest.raises(ConfigError, match=r"must be <= data.scene.stall_time"):
        RefillSettings(interval=1.0).validate("data.refill", scene)


def test_input_tops_up_every_interval_with_its_own_seed_and_time(scene):
    settings = RefillSettings(interval=0.025)
    geom = HopperGeometry.for_angle(scene, 45.0)
    n = n_intervals(scene, settings)
    assert n == 80  # 2 s / 0.025 s
    text = refill_input(scene, settings, geom, scene.material, prime_seeds(0, 3 + n))
    assert text.count("insert/pack seed") == 1 + n  # the fill + one top-up per interval
    assert "fix tins all property/atom tins scalar yes no no -0.2999" in text  # fill time: first step
    assert "set_property tins 0.0001 " in text and "set_property tins 0.0251 " in text
    assert "fix hold sentinel freeze" in text and "dump snapshots flowing custom" in text
    z_lo, z_hi = refill_region(geom, scene.material, settings)
    assert settled_top(scene, geom) < z_lo < z_hi < geom.wall_height
    with pytest.raises(ValueError, match="needs 83 seeds"):
        refill_input(scene, settings, geom, scene.material, prime_seeds(0, 3))
