"""Stability options of the fluidized-bed surrogate (`model.stability`), validated in one place.

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

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from neuraldem.config import checks
from neuraldem.errors import ConfigError
from neuraldem.models.modules.conservative_advection import SCHEMES

KEY = "model.stability"
MIXING_MODES = ("absolute", "advect")
ADVECTION_FLUXES = ("predicted", "consistent")
LOSS_ON = ("every", "last")
MAX_ENSEMBLE = 16
MAX_ROLLOUT_NOISE = 10.0  # times the one-step error: beyond it the net reads noise, not a state
# the numeric options a rollout may override, and their ranges: every spelling of them (model.stability.*, the
# evaluate and rollout keys, the tools' --flags) is checked here, so the bounds cannot drift apart
ROLLOUT_RANGES = {"rollout_noise": (0.0, MAX_ROLLOUT_NOISE), "advection_correction": (0.0, 1.0)}


def check_rollout_value(option: str, value: Any, key: str | None = None) -> float:
    """`value` of the rollout option `option` (a ROLLOUT_RANGES name) inside its range; the error names `key`,
    the spelling the user typed (default: the option's own name)."""
    lo, hi = ROLLOUT_RANGES[option]
    return checks.number(key or option, value, lo=lo, hi=hi)


@dataclass(frozen=True)
class FbStability:
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
    def from_config(cls, cfg: Mapping[str, Any] | None) -> FbStability:
        cfg = dict(cfg or {})
        known = [f.name for f in fields(cls)]
        unknown = sorted(set(cfg) - set(known))
        if unknown:
            raise ConfigError(f"config key {KEY}.{unknown[0]} is unknown: the stability options are {known} "
                              f"(fix the spelling, e.g. {KEY}.mixing=advect)")
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
        checks.boolean(f"{KEY}.conserve_volume", self.conserve_volume)
        checks.one_of(f"{KEY}.mixing", self.mixing, MIXING_MODES)
        checks.one_of(f"{KEY}.advection_scheme", self.advection_scheme, SCHEMES)
        check_rollout_value("advection_correction", self.advection_correction, f"{KEY}.advection_correction")
        checks.one_of(f"{KEY}.advection_flux", self.advection_flux, ADVECTION_FLUXES)
        if self.advection_flux == "consistent" and self.mixing == "advect" and not self.conserve_volume:
            raise ConfigError(f"config value {KEY}.advection_flux=consistent needs {KEY}.conserve_volume=true: "
                              "fluxes can only carry the solid to a field of the same volume (or set "
                              f"{KEY}.advection_flux=predicted)")
        checks.number(f"{KEY}.flux_consistency", self.flux_consistency, lo=0.0, hi=100.0)
        checks.boolean(f"{KEY}.mirror_alternate", self.mirror_alternate)
        check_rollout_value("rollout_noise", self.rollout_noise, f"{KEY}.rollout_noise")
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
            raise ConfigError(f"config value {KEY}.mixing=advect needs the solids flux in the grid state: set "
                              "data.datamodule.solids_flux=true")
        if self.flux_consistency > 0 and not solids_flux:
            raise ConfigError(f"config value {KEY}.flux_consistency={self.flux_consistency} needs the solids flux in "
                              "the grid state: set data.datamodule.solids_flux=true (or flux_consistency=0)")
        if self.ensemble > 1 and noise_dim < 1:
            raise ConfigError(f"config value {KEY}.ensemble={self.ensemble} needs a stochastic net: set "
                              "model.net.noise_dim=8 (or ensemble=1)")


def rollout_overrides(base: FbStability, mixing: str | None = None, conserve_volume: bool | None = None,
                      advection_correction: float | None = None, advection_flux: str | None = None,
                      mirror_alternate: bool | None = None, rollout_noise: float | None = None) -> FbStability:
    """The options a rollout uses: the checkpoint's, with the rollout-time ones overridden (validated)."""
    d = base.to_dict()
    if rollout_noise is not None:
        d["rollout_noise"] = rollout_noise
    if mirror_alternate is not None:
        d["mirror_alternate"] = mirror_alternate
    if advection_flux is not None:
        d["advection_flux"] = advection_flux
    if advection_correction is not None:
        d["advection_correction"] = advection_correction
    if mixing is not None:
        d["mixing"] = mixing
    if conserve_volume is not None:
        d["conserve_volume"] = conserve_volume
    return FbStability.from_config(d)
