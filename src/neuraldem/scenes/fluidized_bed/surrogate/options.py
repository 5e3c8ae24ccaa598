"""Stability options of the fluidized-bed surrogate, validated in one place.

Two objects. `BedStability` is every option a model trains and rolls out with, what a checkpoint stores (its
`hyper_parameters["stability"]`); the training-only ones are set as `model.stability.<name>`. `RolloutOptions` is
the six that a rollout may change (conserve_volume, mixing, advection_correction, advection_flux, mirror_alternate,
rollout_noise), each None = "as the checkpoint was trained": one Hydra group `rollout` (conf/rollout/) and one
spelling on every command, `rollout.<name>=VALUE` (train, evaluate, `evaluate rollout`, `report fb-select`,
`bench fb_stability`, `bench fb_speed`, `release`). Training reads them from `rollout.*` too (experiment=fb sets
them there), merged into BedStability when the module is built (`training_stability`), so a checkpoint records them
as before. The old spellings are read one more release by `option_aliases` alone.

What each option is for (each measured as an ablation row: results/fluidized_bed/recipe.md, tables in
results/fluidized_bed/options/):

unroll            probabilities of rolling 1, 2, ..., K steps from a data snapshot in a training batch (the
                  datamodule serves K = `data.datamodule.push_forward_steps` target steps). The model is
                  scored on `loss_on`: "every" step it took (the first one always from data: a one-step map
                  is supervised in every batch) or only the "last" (the old push-forward; then unroll[0] must
                  be > 0, or no batch ever trains the one-step map from data).
input_noise       std of Gaussian noise on the training inputs, model units; "auto" = per channel the model's
                  own running one-step error (EMA of the RMS error on training batches), so the noise is as
                  large as the errors a rollout feeds back, not a guess 10-100x below them.
conserve_volume   the predicted solid fraction is clamped >= 0 and scaled to the input state's solid volume
                  inside every step, in training (the loss sees the projected field) and in rollouts.
mixing            "absolute": the mixing off-branch re-predicts the concentration every step; "advect": the
                  concentration is carried by the predicted solids flux with a conservative, bounded scheme
                  (`models.modules.conservative_advection`; needs data.datamodule.solids_flux=true).
advection_scheme  "fct" (flux-corrected) or "upwind" (more numerical mixing).
advection_correction  weight of the flux correction, 0 (upwind) .. 1 (full FCT); 0.75 was the best of
                  0 / 0.25 / 0.5 / 0.75 / 1 with CFD-DEM's own fields on the training and validation
                  trajectories (`neuraldem.scenes.fluidized_bed.analysis.advection_oracle --part train+val`): full FCT
                  under-mixes the bubbling beds, upwind over-mixes the quiet ones.
advection_flux    "predicted": the scheme moves the solid with the predicted flux as it is; "consistent": the
                  flux first gets the smallest gradient correction that carries the input solid fraction to the
                  step's (projected) prediction, so the concentration pairs with the solid it describes and the
                  tagged volume is kept from step to step, not only within one (needs conserve_volume=true;
                  what the limiter cannot carry is settled at the pooled concentration). Measured on the
                  training and validation trajectories (`advection_oracle --flux consistent`, results/
                  fluidized_bed/options/advection_calibration/): with CFD-DEM's own fields (22 trajectories,
                  correction 0.75) the largest tagged-volume swing over 3 s fell from 26 % to 0 % and the Lacey
                  MAE from 0.038 to 0.023.
flux_consistency  weight of a loss on the continuity of the predicted step: the predicted solids flux must carry
                  the input solid fraction to the predicted next one (`autoregressive.continuity_residual`, in
                  units of the data's RMS one-step change). 0 = off. Why: the gradient correction that
                  advection_flux=consistent applies was 31-35 % of the model's flux against 15-17 % of CFD-DEM's
                  own (results/fluidized_bed/options/flux_diagnostic/ema2000_seed1.md); that correction,
                  not the learned flux, then set the model's mixing. Needs data.datamodule.solids_flux=true.
mirror_alternate  rollouts only: every other step is taken in the mirror image of the bed (state mirrored in x,
                  stepped, mirrored back; `neuraldem.scenes.fluidized_bed.surrogate.mirror`). The bed is left-right
                  symmetric, a trained net is not quite: its small lean to one wall, applied every step, builds
                  a persistent bubble channel on that side (the 3000-step time means of 8000-step nets leaned by
                  up to 11 % of the bubbling to one side where CFD-DEM's lean < 2 %, results/fluidized_bed/
                  recipe.md). Alternating flips the lean's sign
                  each step so it cancels; the cost is nothing (the same one forward pass per step).
rollout_noise     rollouts only: each step the net reads its input state plus Gaussian noise of this many times
                  the model's running one-step error per channel (what `input_noise=auto` trained it to
                  tolerate); the volume projection and the mixing advection still act on the clean state, so
                  the solid volume and the tagged volume are kept exactly. 0 = off. Why: a deterministic step
                  settles into its most likely bubble path (plain rollouts keep the bubbles to the middle of the
                  bed: std-field share next to the walls 0.26 - 0.28 where CFD-DEM has 0.29, 0.28 - 0.31 with
                  noise 3; results/fluidized_bed/options/rollout_noise_val.md); perturbations of the size of its
                  own error let the paths wander as a chaotic bed's do, at no cost per step. Needs a model that
                  records the running one-step error (input_noise=auto).
ensemble          members per training sample: 1 = deterministic (MSE); >= 2 = a stochastic model (net
                  noise_dim > 0) trained with the fair CRPS over its members.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from neuraldem.cli import FALSE, TRUE
from neuraldem.config import checks
from neuraldem.errors import ConfigError
from neuraldem.models.modules.conservative_advection import SCHEMES
from neuraldem.scenes.fluidized_bed.surrogate import option_aliases

KEY = "model.stability"
GROUP = "rollout"  # the Hydra group of the rollout options and their key prefix on every command
MIXING_MODES = ("absolute", "advect")
ADVECTION_FLUXES = ("predicted", "consistent")
LOSS_ON = ("every", "last")
MAX_ENSEMBLE = 16
MAX_ROLLOUT_NOISE = 10.0  # times the one-step error: beyond it the net reads noise, not a state


@dataclass(frozen=True)
class OptionSpec:
    """What values one rollout option takes: "bool", "choice" (of `choices`) or "number" (in [lo, hi])."""

    kind: str
    help: str
    example: str
    choices: tuple[str, ...] = ()
    lo: float = 0.0
    hi: float = 0.0

    @property
    def values(self) -> str:
        """The values, as the usage line and the errors say them."""
        if self.kind == "bool":
            return "true|false"
        if self.kind == "choice":
            return "|".join(self.choices)
        return f"{self.lo:g}..{self.hi:g}"

    def requirement(self) -> str:
        if self.kind == "bool":
            return "must be true or false"
        if self.kind == "choice":
            return f"must be one of {', '.join(self.choices)}"
        return f"must be a number in [{self.lo:g}, {self.hi:g}]"


# the six options a rollout may change, in the order of RolloutOptions' fields; every spelling of them is checked
# here, so the ranges and choices cannot drift apart
OPTION_SPECS: dict[str, OptionSpec] = {
    "conserve_volume": OptionSpec("bool", "clamp >= 0 and scale the solid fraction to the input state's volume "
                                  "inside every step", "true"),
    "mixing": OptionSpec("choice", "absolute: re-predict the mixing concentration every step; advect: carry it "
                         "with the predicted solids flux", "advect", choices=MIXING_MODES),
    "advection_correction": OptionSpec("number", "mixing=advect: weight of the flux correction, 0 (upwind) .. 1 "
                                       "(full FCT)", "0.75", lo=0.0, hi=1.0),
    "advection_flux": OptionSpec("choice", "mixing=advect: predicted, or consistent (corrected to carry the "
                                 "solid to the projected next field; needs conserve_volume=true)", "consistent",
                                 choices=ADVECTION_FLUXES),
    "mirror_alternate": OptionSpec("bool", "every second step in the mirror image of the bed (cancels a net's "
                                   "left-right lean)", "true"),
    "rollout_noise": OptionSpec("number", "the net reads each state + Gaussian noise of this many times its "
                                "one-step error (0 = off)", "3", lo=0.0, hi=MAX_ROLLOUT_NOISE),
}
OPTION_NAMES = tuple(OPTION_SPECS)
ROLLOUT_RANGES = {name: (s.lo, s.hi) for name, s in OPTION_SPECS.items() if s.kind == "number"}


def option_key(name: str) -> str:
    """How a user types rollout option `name` on every command: `rollout.<name>`."""
    return f"{GROUP}.{name}"


def typed(value: Any) -> str:
    """A value as it is typed on a command line (true, 3, 0.75, advect)."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def check_option(name: str, value: Any, key: str | None = None) -> Any:
    """`value` of rollout option `name` if valid; else one line naming `key` (default `rollout.<name>`), the
    values it takes and an example."""
    spec, key = OPTION_SPECS[name], key or option_key(name)
    if spec.kind == "bool":
        ok = isinstance(value, bool)
    elif spec.kind == "choice":
        ok = isinstance(value, str) and value in spec.choices
    else:
        ok = (not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
              and spec.lo <= value <= spec.hi)
    if not ok:
        shown = typed(value) if isinstance(value, (bool, int, float, str)) else repr(value)
        raise ConfigError(f"{key}={shown} is invalid: {spec.requirement()} (e.g. {key}={spec.example})")
    return value


def check_flux(conserve_volume: Any, mixing: Any, advection_flux: Any) -> None:
    """A consistent flux carries the solid to a field of the same volume: with the mixing advected it needs
    the volume projection."""
    if advection_flux == "consistent" and mixing == "advect" and conserve_volume is False:
        raise ConfigError(f"{option_key('advection_flux')}=consistent needs {option_key('conserve_volume')}=true: "
                          "fluxes can only carry the solid to a field of the same volume (or set "
                          f"{option_key('advection_flux')}=predicted)")


def parse_text(name: str, text: str) -> Any:
    """A command line's text of rollout option `name` as its value (checked by `check_option`)."""
    spec = OPTION_SPECS[name]
    if spec.kind == "bool":
        lowered = text.lower()
        return True if lowered in TRUE else False if lowered in FALSE else text
    if spec.kind == "number":
        try:
            return float(text)
        except ValueError:
            return text
    return text


@dataclass(frozen=True)
class RolloutOptions:
    """The rollout options a command was given; None = as the checkpoint was trained. Validated when made."""

    conserve_volume: bool | None = None
    mixing: str | None = None
    advection_correction: float | None = None
    advection_flux: str | None = None
    mirror_alternate: bool | None = None
    rollout_noise: float | None = None

    def __post_init__(self) -> None:
        for name, value in self.given().items():
            check_option(name, value)
        check_flux(self.conserve_volume, self.mixing, self.advection_flux)

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any] | None, key: str = GROUP) -> RolloutOptions:
        """From the `rollout` group of a config (or any mapping of option names); an unknown key is refused."""
        values = dict(cfg or {})
        unknown = sorted(set(values) - set(OPTION_NAMES))
        if unknown:
            raise ConfigError(f"config key {key}.{unknown[0]} is unknown: the rollout options are "
                              f"{', '.join(option_key(n) for n in OPTION_NAMES)} (fix the spelling, e.g. "
                              f"{option_key('rollout_noise')}=3)")
        return cls(**values)

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> RolloutOptions:
        """From a command's parsed options (`add_arguments`): the values typed, None for those left out."""
        values = {}
        for name in OPTION_NAMES:
            text = getattr(args, option_key(name), None)
            if text is not None:
                values[name] = parse_text(name, text) if isinstance(text, str) else text
        return cls(**values)

    def given(self) -> dict[str, Any]:
        """The options that were set (not None), by name."""
        return {name: value for name, value in self.as_dict().items() if value is not None}

    def as_dict(self, names: Iterable[str] = OPTION_NAMES) -> dict[str, Any]:
        return {name: getattr(self, name) for name in names}

    def apply(self, stability: BedStability) -> BedStability:
        """The options a rollout uses: the checkpoint's, with the given ones replaced (validated together)."""
        given = self.given()
        return BedStability.from_config({**stability.to_dict(), **given}) if given else stability

    def tag(self) -> str:
        """A folder name for these options, from the given ones: `rollout_noise-3+mirror_alternate-true`
        (`as_trained` when none is given), so that results under other options never share a folder."""
        return "+".join(f"{name}-{typed(value)}" for name, value in self.given().items()) or "as_trained"

    def overrides(self) -> list[str]:
        """The given options as every command takes them: `rollout.rollout_noise=3 ...`."""
        return [f"{option_key(name)}={typed(value)}" for name, value in self.given().items()]


def add_arguments(p: argparse.ArgumentParser, names: Iterable[str] = OPTION_NAMES,
                  default: str = "as the checkpoint was trained") -> None:
    """The rollout options `names` as a command's options `rollout.<name>=VALUE` (argparse dest
    `rollout.<name>`; read them back with `RolloutOptions.from_args`). The values are kept as typed and checked
    when the RolloutOptions is made, so a bad one ends in the same line on every command."""
    names = list(names)
    option_aliases.add_old_flags(p, names)  # hidden: not keys (neuraldem.cli), only old flags read into the same dest
    for name in names:
        spec = OPTION_SPECS[name]
        p.add_argument(f"--{option_key(name)}", dest=option_key(name), default=None, metavar=spec.values,
                       help=f"{spec.help} (default: {default})")


def training_stability(stability: Mapping[str, Any] | None, rollout: Mapping[str, Any] | None) -> dict[str, Any]:
    """The stability options a model trains with: `model.stability` with the `rollout` group's given options
    in place (a checkpoint then stores them as it always did). Old spellings in `model.stability` are read with
    a note (`option_aliases`)."""
    stability, rollout = option_aliases.moved_stability_options(dict(stability or {}), dict(rollout or {}))
    return {**stability, **RolloutOptions.from_config(rollout).given()}


@dataclass(frozen=True)
class BedStability:
    unroll: tuple[float, ...] = (1.0,)
    loss_on: str = "every"
    input_noise: float | str = 0.0
    conserve_volume: bool = False
    mixing: str = "absolute"
    advection_scheme: str = "fct"
    advection_correction: float = 0.75
    advection_flux: str = "predicted"  # checkpoints saved before the option keep their behaviour
    flux_consistency: float = 0.0
    mirror_alternate: bool = False
    rollout_noise: float = 0.0
    ensemble: int = 1
    noise_ema: float = field(default=0.99, repr=False)

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any] | None) -> BedStability:
        cfg = dict(cfg or {})
        known = [f.name for f in fields(cls)]
        unknown = sorted(set(cfg) - set(known))
        if unknown:
            raise ConfigError(f"config key {KEY}.{unknown[0]} is unknown: the stability options are {known} "
                              f"(fix the spelling, e.g. {KEY}.input_noise=auto)")
        return cls(**cfg)

    def __post_init__(self) -> None:
        probs = self.unroll
        if isinstance(probs, (int, float)) or not probs:
            raise ConfigError(f"config value {KEY}.unroll={probs!r} is invalid: give the probabilities of "
                              f"unrolling 1, 2, ... steps, e.g. {KEY}.unroll=[0.5,0.3,0.2]")
        probs = tuple(checks.number(f"{KEY}.unroll[{i}]", p, lo=0.0) for i, p in enumerate(probs))
        if abs(sum(probs) - 1.0) > 1e-6:
            raise ConfigError(f"config value {KEY}.unroll={list(probs)} is invalid: the probabilities must sum to 1 "
                              f"(e.g. {KEY}.unroll=[0.5,0.3,0.2])")
        object.__setattr__(self, "unroll", probs)
        checks.one_of(f"{KEY}.loss_on", self.loss_on, LOSS_ON)
        if self.loss_on == "last" and probs[0] == 0:
            raise ConfigError(f"config value {KEY}.unroll={list(probs)} with {KEY}.loss_on=last never trains the "
                              f"one-step map from data: give unroll[0] > 0 or use {KEY}.loss_on=every")
        if self.input_noise != "auto":
            checks.number(f"{KEY}.input_noise", self.input_noise, lo=0.0, hi=1.0)
        for name in OPTION_NAMES:  # the rollout options: their checks and keys (rollout.<name>) are RolloutOptions'
            check_option(name, getattr(self, name))
        check_flux(self.conserve_volume, self.mixing, self.advection_flux)
        checks.one_of(f"{KEY}.advection_scheme", self.advection_scheme, SCHEMES)
        checks.number(f"{KEY}.flux_consistency", self.flux_consistency, lo=0.0, hi=100.0)
        if isinstance(self.ensemble, bool) or not isinstance(self.ensemble, int) or self.ensemble < 1:
            raise ConfigError(f"config value {KEY}.ensemble={self.ensemble!r} is invalid: must be an integer >= 1 "
                              f"(1 = deterministic; 2 = a stochastic model trained with CRPS, e.g. {KEY}.ensemble=2)")
        if self.ensemble > MAX_ENSEMBLE:
            raise ConfigError(f"config value {KEY}.ensemble={self.ensemble} is invalid: must be <= {MAX_ENSEMBLE} "
                              f"(each member costs a forward pass; e.g. {KEY}.ensemble=2)")
        checks.number(f"{KEY}.noise_ema", self.noise_ema, lo=0.0, hi=1.0, hi_open=True)

    @property
    def max_unroll(self) -> int:
        return len(self.unroll)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["unroll"] = list(self.unroll)
        return d

    def check_fits(self, served_steps: int, solids_flux: bool, noise_dim: int) -> None:
        """The data and the net must provide what the options use; say which key to change."""
        if self.max_unroll > served_steps:
            raise ConfigError(f"config value {KEY}.unroll has {self.max_unroll} entries but the datamodule serves "
                              f"{served_steps} target step(s): set data.datamodule.push_forward_steps="
                              f"{self.max_unroll}")
        if self.mixing == "advect" and not solids_flux:
            raise ConfigError(f"config value {option_key('mixing')}=advect needs the solids flux in the grid state: "
                              "set data.datamodule.solids_flux=true")
        if self.flux_consistency > 0 and not solids_flux:
            raise ConfigError(f"config value {KEY}.flux_consistency={self.flux_consistency} needs the solids flux in "
                              "the grid state: set data.datamodule.solids_flux=true (or flux_consistency=0)")
        if self.ensemble > 1 and noise_dim < 1:
            raise ConfigError(f"config value {KEY}.ensemble={self.ensemble} needs a stochastic net: set "
                              "model.net.noise_dim=8 (or ensemble=1)")

