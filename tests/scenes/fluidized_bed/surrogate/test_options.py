"""The fluidized-bed stability options: every training configuration supervises the one-step map from data,
and bad values end in one line that names the key and the fix. The rollout options (`RolloutOptions`): one
object, one spelling (`rollout.<name>`), the same checks on every command."""

from __future__ import annotations

from dataclasses import fields

import pytest

from neuraldem.cli import CommandParser
from neuraldem.errors import ConfigError
from neuraldem.paths import config_dir
from neuraldem.scenes.fluidized_bed.surrogate.options import (
    OPTION_NAMES,
    ROLLOUT_RANGES,
    BedStability,
    RolloutOptions,
    add_arguments,
    check_option,
)
from neuraldem.train import model_kwargs

FB_EXPERIMENTS = sorted(p.stem for p in (config_dir() / "experiment").glob("fb*.yaml"))
FB_MODELS = sorted(p.stem for p in (config_dir() / "model").glob("fb_*.yaml"))


def _one_step_supervised(s: BedStability) -> bool:
    """A batch scores step 1 (from data) whenever it unrolls one step, or on every step it takes."""
    return s.loss_on == "every" or s.unroll[0] > 0


def trained_with(cfg) -> BedStability:
    """The options a model of a composed training config trains with (`model.stability` + the `rollout` group)."""
    return BedStability.from_config(model_kwargs(cfg)["stability"])


@pytest.mark.parametrize("experiment", FB_EXPERIMENTS)
def test_every_fb_experiment_supervises_one_step(experiment: str, compose_train_cfg):
    cfg = compose_train_cfg(f"experiment={experiment}")
    s = trained_with(cfg)
    assert _one_step_supervised(s)
    assert s.max_unroll <= cfg.data.datamodule.push_forward_steps


@pytest.mark.parametrize("model", FB_MODELS)
def test_every_fb_model_default_supervises_one_step(model: str, compose_train_cfg):
    cfg = compose_train_cfg("experiment=fb_quick", f"model={model}")
    assert _one_step_supervised(trained_with(cfg))


def test_the_fb_experiment_uses_the_recipe_options(compose_train_cfg):
    s = trained_with(compose_train_cfg("experiment=fb"))
    assert s.unroll == (0.5, 0.3, 0.2) and s.loss_on == "every" and s.input_noise == "auto"
    assert s.conserve_volume and s.mixing == "advect" and s.advection_flux == "consistent"
    # the rollout options are set in the rollout group, the others are BedStability's defaults, as before
    assert (s.advection_correction, s.mirror_alternate, s.rollout_noise) == (0.75, False, 0.0)
    noisy = trained_with(compose_train_cfg("experiment=fb", "rollout.rollout_noise=3", "rollout.mixing=absolute"))
    assert noisy.rollout_noise == 3 and noisy.mixing == "absolute" and noisy.unroll == s.unroll


@pytest.mark.parametrize("cfg,message", [
    ({"mixng": "advect"},
     r"config key model\.stability\.mixng is unknown: the stability options are .*fix the spelling"),
    ({"ensemble": 0}, r"model\.stability\.ensemble=0 is invalid: must be an integer >= 1"),
    ({"ensemble": -2}, r"model\.stability\.ensemble=-2 is invalid"),
    ({"ensemble": 1.5}, r"model\.stability\.ensemble=1\.5 is invalid"),
    ({"unroll": [0.0, 1.0], "loss_on": "last"}, r"never trains the one-step map from data"),
    ({"unroll": [0.5, 0.3]}, r"probabilities must sum to 1"),
    ({"unroll": []}, r"model\.stability\.unroll=\[\] is invalid"),
    ({"unroll": [1.2, -0.2]}, r"model\.stability\.unroll\[1\]=-0\.2 is invalid"),
    ({"loss_on": "first"}, r"model\.stability\.loss_on='first' is invalid: must be one of \['every', 'last'\]"),
    ({"mixing": "diffuse"}, r"rollout\.mixing=diffuse is invalid: must be one of absolute, advect"),
    ({"input_noise": "big"}, r"model\.stability\.input_noise='big' is invalid"),
    ({"conserve_volume": "yes"}, r"rollout\.conserve_volume=yes is invalid: must be true or false"),
    ({"advection_scheme": "weno"}, r"model\.stability\.advection_scheme='weno' is invalid"),
    ({"advection_flux": "smooth"}, r"rollout\.advection_flux=smooth is invalid: must be one of predicted, consistent"),
    ({"advection_flux": "consistent", "mixing": "advect"},
     r"rollout\.advection_flux=consistent needs rollout\.conserve_volume=true"),
    ({"flux_consistency": -0.5}, r"model\.stability\.flux_consistency=-0\.5 is invalid: must be >= 0"),
    ({"flux_consistency": "strong"}, r"model\.stability\.flux_consistency='strong' is invalid"),
    ({"mirror_alternate": "yes"}, r"rollout\.mirror_alternate=yes is invalid: must be true or false"),
    ({"rollout_noise": 12}, r"rollout\.rollout_noise=12 is invalid: must be a number in \[0, 10\]"),
])
def test_bad_stability_options_end_in_one_line(cfg: dict, message: str):
    with pytest.raises(ConfigError, match=message) as err:
        BedStability.from_config(cfg)
    assert "\n" not in str(err.value)


def test_options_must_fit_the_data_and_the_net():
    with pytest.raises(ConfigError, match=r"serves 1 target step.*push_forward_steps=3"):
        BedStability(unroll=(0.5, 0.3, 0.2)).check_fits(1, True, 0)
    with pytest.raises(ConfigError, match=r"mixing=advect needs the solids flux.*solids_flux=true"):
        BedStability(mixing="advect").check_fits(1, False, 0)
    with pytest.raises(ConfigError, match=r"ensemble=2 needs a stochastic net.*noise_dim"):
        BedStability(ensemble=2).check_fits(1, False, 0)
    with pytest.raises(ConfigError, match=r"flux_consistency=0\.5 needs the solids flux.*solids_flux=true"):
        BedStability(flux_consistency=0.5).check_fits(1, False, 0)
    BedStability(unroll=(0.5, 0.5), mixing="advect", ensemble=2).check_fits(2, True, 8)  # fits


def test_rollout_options_replace_the_checkpoint_s_and_keep_the_rest():
    base = BedStability(unroll=(0.5, 0.5), input_noise="auto", conserve_volume=True)
    r = RolloutOptions(mixing="advect", conserve_volume=False).apply(base)
    assert (r.mixing, r.conserve_volume, r.unroll, r.input_noise) == ("advect", False, (0.5, 0.5), "auto")
    assert RolloutOptions().apply(base) == base
    with pytest.raises(ConfigError, match="rollout.mixing=both is invalid"):
        RolloutOptions(mixing="both")
    r = RolloutOptions(mixing="advect", advection_flux="consistent").apply(base)
    assert r.advection_flux == "consistent" and r.conserve_volume
    with pytest.raises(ConfigError, match="rollout.advection_flux=consistent needs rollout.conserve_volume=true"):
        RolloutOptions(conserve_volume=False).apply(r)  # the projection switched off under a consistent flux
    assert RolloutOptions(mirror_alternate=True).apply(base).mirror_alternate and not base.mirror_alternate
    with pytest.raises(ConfigError, match="rollout.mirror_alternate=1 is invalid"):
        RolloutOptions(mirror_alternate=1)


BAD_VALUES = {"conserve_volume": ("maybe", "true or false"), "mixing": ("stir", "one of absolute, advect"),
              "advection_correction": (2, "a number in [0, 1]"), "advection_flux": ("smooth", "one of predicted"),
              "mirror_alternate": ("maybe", "true or false"), "rollout_noise": (-1, "a number in [0, 10]")}


@pytest.mark.parametrize("name", OPTION_NAMES)
def test_a_bad_rollout_option_is_one_line_naming_its_key(name: str):
    """The same line from a config (Hydra's `rollout.<name>=`) and from a tool's command line."""
    value, requirement = BAD_VALUES[name]
    with pytest.raises(ConfigError) as from_config:
        RolloutOptions.from_config({name: value})
    p = CommandParser(prog="tool")
    add_arguments(p)
    with pytest.raises(ConfigError) as from_args:
        RolloutOptions.from_args(p.parse_args([f"rollout.{name}={value}"]))
    for err in (from_config, from_args):
        message = str(err.value)
        assert message.startswith(f"rollout.{name}={value} is invalid: must be {requirement}"), message
        assert "\n" not in message and f"(e.g. rollout.{name}=" in message  # the fix
    with pytest.raises(ConfigError, match=rf"rollout\.{name}=.* is invalid"):  # what a checkpoint stores too
        BedStability.from_config({name: value})


def test_an_unknown_rollout_option_lists_the_six():
    with pytest.raises(ConfigError, match="config key rollout.noise is unknown: the rollout options are "
                                          "rollout.conserve_volume, rollout.mixing, .*rollout.rollout_noise") as err:
        RolloutOptions.from_config({"noise": 3})
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("given,tag,overrides", [
    ({}, "as_trained", []),
    ({"rollout_noise": 3.0}, "rollout_noise-3", ["rollout.rollout_noise=3"]),
    ({"mirror_alternate": True, "advection_correction": 1, "rollout_noise": 0.5},
     "advection_correction-1+mirror_alternate-true+rollout_noise-0.5",
     ["rollout.advection_correction=1", "rollout.mirror_alternate=true", "rollout.rollout_noise=0.5"]),
    ({"conserve_volume": False, "mixing": "advect", "advection_flux": "predicted", "mirror_alternate": False},
     "conserve_volume-false+mixing-advect+advection_flux-predicted+mirror_alternate-false",
     ["rollout.conserve_volume=false", "rollout.mixing=advect", "rollout.advection_flux=predicted",
      "rollout.mirror_alternate=false"]),
])
def test_tag_and_overrides_round_trip(given: dict, tag: str, overrides: list[str]):
    """The folder tag and the command-line form come from the options given; typed back on a command (or as a
    config), the overrides give the same options."""
    options = RolloutOptions(**given)
    assert options.tag() == tag and options.overrides() == overrides
    p = CommandParser(prog="tool")
    add_arguments(p)
    assert RolloutOptions.from_args(p.parse_args(overrides)) == options
    assert RolloutOptions.from_config(options.as_dict()) == options


@pytest.mark.parametrize("option", sorted(ROLLOUT_RANGES))
def test_every_spelling_of_a_rollout_option_has_one_range(option):
    """RolloutOptions, BedStability (what a checkpoint stores) and the tools' options take the same bounds."""
    lo, hi = ROLLOUT_RANGES[option]
    assert check_option(option, hi) == hi and check_option(option, lo) == lo
    above = hi + 0.5
    for make in (lambda: BedStability.from_config({option: above}), lambda: RolloutOptions(**{option: above})):
        with pytest.raises(ConfigError, match=rf"rollout\.{option}={above:g} is invalid"):
            make()


def test_the_option_table_is_the_object():
    """One declaration: the specs (checks, help, tags, keys) list RolloutOptions' fields in their order."""
    assert [f.name for f in fields(RolloutOptions)] == list(OPTION_NAMES)
    assert set(OPTION_NAMES) <= {f.name for f in fields(BedStability)}  # what a checkpoint stores
