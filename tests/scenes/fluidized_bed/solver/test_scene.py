"""The fluidized-bed scene: defaults, checks naming the bad key, and the random start packing."""

from __future__ import annotations

import numpy as np
import pytest
from omegaconf import OmegaConf

from neuraldem.errors import ConfigError
from neuraldem.scenes.fluidized_bed.solver.scene import BedScene, random_packing
from tests.helpers import REPO


def test_scene_defaults_match_the_canonical_config():
    scene = BedScene.from_config(OmegaConf.load(REPO / "conf/data/fb_small.yaml").scene, "data.scene")
    assert scene == BedScene()
    assert scene.minimum_fluidization_velocity == pytest.approx(1.07, abs=0.01)
    assert scene.grid.shape == (12, 1, 30) and scene.grid.cell_volume == pytest.approx(0.004 * 0.006 * 0.004)


@pytest.mark.parametrize("override,message", [
    ({"cells": [12, 1]}, "data.scene.cells"),
    ({"drag": "Stokes"}, "data.scene.drag='Stokes' is invalid"),
    ({"snapshot_interval": 0.00015}, "multiple of data.scene.dt"),
    ({"spinup_time": 0.015}, "spinup_time=0.015 is invalid"),
    ({"n_particles": 20000}, "start packing"),
    ({"front_back": "periodic"}, "data.scene.front_back"),
    ({"colour": "red"}, "unknown key"),
])
def test_bad_scene_values_name_the_key(override: dict, message: str):
    with pytest.raises(ConfigError, match=message):
        BedScene.from_config(override, "data.scene")


def test_random_packing_has_no_overlaps_and_differs_by_seed(tiny_scene):
    scene = tiny_scene
    a = random_packing(scene, np.random.default_rng(1))
    b = random_packing(scene, np.random.default_rng(2))
    assert a.shape == (300, 3) and not np.allclose(a, b)
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(a).query(a, k=2)
    assert dist[:, 1].min() >= scene.diameter
    r = scene.diameter / 2
    assert np.all(a >= r) and np.all(a <= np.array([scene.width, scene.thickness, scene.height]) - r)
