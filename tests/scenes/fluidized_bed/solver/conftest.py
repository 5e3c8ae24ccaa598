"""The scene the solver tests run: fb_small shrunk by fb_tiny (the test datasets' scene)."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from neuraldem.scenes.fluidized_bed.solver.scene import BedScene
from tests.helpers import REPO


@pytest.fixture(scope="module")
def tiny_scene() -> BedScene:
    cfg = OmegaConf.merge(OmegaConf.load(REPO / "conf/data/fb_small.yaml").scene,
                          OmegaConf.load(REPO / "conf/data/fb_tiny.yaml").scene)
    return BedScene.from_config(cfg, "data.scene")
