"""The fluidized-bed stability options: every training configuration supervises the one-step map from data,
and bad values end in one line that names the key and the fix."""

from __future__ import annotations

import pytest

from neuraldem.errors import ConfigError
from neuraldem.paths import config_dir
from neuraldem.scenes.fluidized_bed.surrogate.options import (
    ROLLOUT_RANGES,
    FbStability,
    check_rollout_value,
    rollout_overrides,
)
from neuraldem.scenes.fluidized_bed.surrogate.rollout_flags import check_rollout_flags

FB_EXPERIMENTS = sorted(p.stem for p in (config_dir() / "experiment").glob("fb*.yaml"))
FB_MODELS = sorted(p.stem for p in (config_dir() / "model").glob("fb_*.yaml"))


def _one_step_supervised(s: FbStability) -> bool:
    """A batch scores step 1 (from data) whenever it unrolls one step, or on every step it takes."""
    return s.loss_on == "every" or s.unroll[0] > 0


@pytest.mark.parametrize("experiment", FB_EXPERIMENTS)
def test_every_fb_experiment_supervises_one_step(experiment: str, compose_train_cfg):
    cfg = compose_train_cfg(f"experiment={experiment}")
    s = FbStability.from_config(cfg.model.stability)
    assert _one_step_supervised(s)
    assert s.max_unroll <= cfg.data.datamodule.push_forward_steps


@pytest.mark.parametrize("model", FB_MODELS)
def test_every_fb_model_default_supervises_one_step(model: str, compose_train_cfg):
    cfg = compose_train_cfg("experiment=fb_quick", f"model={model}")
    assert _one_step_supervised(FbStability.from_config(cfg.model.stability))


def test_the_fb_experiment_uses_the_recipe_options(compose_train_cfg):
    s = FbStability.from_config(compose_train_cfg("experiment=fb").model.stability)
    assert s.unroll == (0.5, 0.3, 0.2) and s.loss_on == "every" and s.input_noise == "auto"
    assert s.conserve_volume and s.mixing == "advect" and s.advection_flux == "consistent"


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
    ({"mixing": "diffuse"}, r"model\.stability\.mixing='diffuse' is invalid"),
    ({"input_noise": "big"}, r"model\.stability\.input_noise='big' is invalid"),
    ({"conserve_volume": "yes"}, r"model\.stability\.conserve_volume='yes' is invalid"),
    ({"advection_scheme": "weno"}, r"model\.stability\.advection_scheme='weno' is invalid"),
    ({"advection_flux": "smooth"}, r"model\.stability\.advection_flux='smooth' is invalid: must be one of "
                                   r"\['predicted', 'consistent'\]"),
    ({"advection_flux": "consistent", "mixing": "advect"},
     r"advection_flux=consistent needs model\.stability\.conserve_volume=true"),
    ({"flux_consistency": -0.5}, r"model\.stability\.flux_consistency=-0\.5 is invalid: must be >= 0"),
    ({"flux_consistency": "strong"}, r"model\.stability\.flux_consistency='strong' is invalid"),
    ({"mirror_alternate": "yes"}, r"model\.stability\.mirror_alternate='yes' is invalid: must be true or false"),
])
def test_bad_stability_options_end_in_one_line(cfg: dict, message: str):
    with pytest.raises(ConfigError, match=message) as err:
        FbStability.from_config(cfg)
    assert "\n" not in str(err.value)


def test_options_must_fit_the_data_and_the_net():
    with pytest.raises(ConfigError, match=r"serves 1 target step.*push_forward_steps=3"):
        FbStability(unroll=(0.5, 0.3, 0.2)).check_fits(1, True, 0)
    with pytest.raises(ConfigError, match=r"mixing=advect needs the solids flux.*solids_flux=true"):
        FbStability(mixing="advect").check_fits(1, False, 0)
    with pytest.raises(ConfigError, match=r"ensemble=2 needs a stochastic net.*noise_dim"):
        FbStability(ensemble=2).check_fits(1, False, 0)
    with pytest.raises(ConfigError, match=r"flux_consistency=0\.5 needs the solids flux.*solids_flux=true"):
        FbStability(flux_consistency=0.5).check_fits(1, False, 0)
    FbStability(unroll=(0.5, 0.5), mixing="advect", ensemble=2).check_fits(2, True, 8)  # fits


def test_rollout_overrides_are_validated_and_keep_the_rest():
    base = FbStability(unroll=(0.5, 0.5), input_noise="auto", conserve_volume=True)
    r = rollout_overrides(base, mixing="advect", conserve_volume=False)
    assert (r.mixing, r.conserve_volume, r.unroll, r.input_noise) == ("advect", False, (0.5, 0.5), "auto")
    assert rollout_overrides(base) == base
    with pytest.raises(ConfigError, match="mixing='both'"):
        rollout_overrides(base, mixing="both")
    r = rollout_overrides(base, mixing="advect", advection_flux="consistent")
    assert r.advection_flux == "consistent" and r.conserve_volume
    with pytest.raises(ConfigError, match="advection_flux=consistent needs"):  # the projection switched off
        rollout_overrides(r, conserve_volume=False)
    assert rollout_overrides(base, mirror_alternate=True).mirror_alternate and not base.mirror_alternate
    with pytest.raises(ConfigError, match="mirror_alternate=1 is invalid"):
        rollout_overrides(base, mirror_alternate=1)


@pytest.mark.parametrize("option", sorted(ROLLOUT_RANGES))
def test_every_spelling_of_a_rollout_option_has_one_range(option):
    """model.stability.*, the tools' --flags and the evaluate / rollout keys take the same bounds, each error
    naming the spelling that was typed."""
    lo, hi = ROLLOUT_RANGES[option]
    assert check_rollout_value(option, hi) == hi and check_rollout_value(option, lo) == lo
    above, below = hi + 0.5, lo - 0.5
    with pytest.raises(ConfigError, match=rf"model\.stability\.{option}={above} is invalid"):
        FbStability.from_config({option: above})
    flags = {"rollout_noise": (above, None), "advection_correction": (None, above)}[option]
    with pytest.raises(ConfigError, match=rf"--{option.replace('_', '-')}={above} is invalid"):
        check_rollout_flags(*flags)
    with pytest.raises(ConfigError, match=rf"fluidized_bed\.{option}={below} is invalid"):
        check_rollout_value(option, below, f"fluidized_bed.{option}")
