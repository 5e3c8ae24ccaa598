"""The scene registry: every built-in kind resolves to its own scene with all parts, unknown kinds are refused in
one line naming how to add one, names and aliases resolve, and the generic commands go through it (datagen's
pipeline comes from the scene, a checkpoint's module class from its scene)."""

from __future__ import annotations

import importlib

import pytest
from omegaconf import OmegaConf

from neuraldem.datagen.__main__ import make_pipeline
from neuraldem.errors import ConfigError
from neuraldem.paths import config_dir
from neuraldem.scenes import BUILT_IN, Scene, by_name, import_class, kinds, scene


@pytest.mark.parametrize("kind", BUILT_IN)
def test_each_kind_has_its_scene(kind: str):
    s = scene(kind)
    assert isinstance(s, Scene) and s.kind == kind and kind in kinds()
    assert s.experiment.startswith("experiment=") and s.parameters.names
    assert all(callable(f) for f in (s.pipeline, s.evaluate, s.evaluate_run))
    assert import_class(s.module).__name__.endswith("Module")
    for ref in filter(None, (s.whatif, s.scan, s.page, s.release)):
        importlib.import_module(ref)  # every part named exists
    for module, _ in [*s.benchmarks.values(), *s.reports.values(), *s.exports.values()]:
        assert callable(importlib.import_module(module.partition(":")[0]).main), module


def test_an_unknown_kind_names_the_key_the_choices_and_how_to_add_one():
    with pytest.raises(ConfigError, match=r"data.kind='drum' is invalid: the scenes are 'hopper', 'hopper_refill'"
                                          r".*NEURALDEM_SCENES=FOLDER"):
        scene("drum")
    with pytest.raises(ConfigError, match="config value data.kind=None"):
        make_pipeline(OmegaConf.create({"name": "x"}))


def test_names_and_aliases():
    assert by_name("fluidized_bed") is by_name("fb") is by_name("bed") is scene("fluidized_bed")
    assert scene("fluidized_bed").route == "bed" and scene("hopper").route == "hopper"
    with pytest.raises(ConfigError, match="unknown scene 'drum': choose one of: hopper, hopper_refill, "
                                          "fluidized_bed / bed / fb"):
        by_name("drum")


def test_experiment_hints_name_existing_experiments():
    for kind in BUILT_IN:
        name = scene(kind).experiment.removeprefix("experiment=")
        assert (config_dir() / "experiment" / f"{name}.yaml").is_file(), name


def test_the_parameter_table_is_the_one_source():
    hopper = scene("hopper").parameters
    assert hopper.names == ["alpha", "mu_s", "mu_r"] and hopper.limits("alpha") == (0.0, 75.0)
    assert hopper.limits("theta") == (float("-inf"), float("inf"))  # a measured scalar: not a solver input
    assert scene("hopper_refill").parameters is hopper
    assert scene("fluidized_bed").parameters.limits("inlet_velocity") == (0.0, 20.0)
    assert "| alpha | deg | 0 .. 75 | cone angle" in hopper.table_markdown()
    with pytest.raises(ConfigError, match=r"parameter alpha=80 is outside what the solver can run \(0 .. 75\)"):
        hopper.check("alpha", [80.0])
