"""The scene registry: every kind resolves to its own scene with all parts, unknown kinds are refused in one
line, and the generic commands go through it (datagen's pipeline comes from the scene)."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from neuraldem.datagen.__main__ import make_pipeline
from neuraldem.errors import ConfigError
from neuraldem.scenes import KINDS, Scene, scene


@pytest.mark.parametrize("kind", KINDS)
def test_each_kind_has_its_scene(kind: str):
    s = scene(kind)
    assert isinstance(s, Scene) and s.kind == kind
    assert s.experiment.startswith("experiment=")
    assert all(callable(f) for f in (s.pipeline, s.evaluate, s.evaluate_run))


def test_an_unknown_kind_names_the_key_and_the_choices():
    with pytest.raises(ConfigError, match=r"data.kind='drum' is invalid: the scenes are 'hopper', 'hopper_refill'"):
        scene("drum")
    with pytest.raises(ConfigError, match="config value data.kind=None"):
        make_pipeline(OmegaConf.create({"name": "x"}))


def test_experiment_hints_name_existing_experiments():
    from neuraldem.paths import config_dir

    for kind in KINDS:
        name = scene(kind).experiment.removeprefix("experiment=")
        assert (config_dir() / "experiment" / f"{name}.yaml").is_file(), name
