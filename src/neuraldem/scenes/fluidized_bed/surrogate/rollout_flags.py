"""The rollout-option flags the bed's command-line tools share (`report fb-select`, `bench fb_stability`,
`bench fb_speed`): one spelling, one help text and one range check, so that a model is chosen, mapped and timed
under options given the same way. Each flag left out (None) means "as the checkpoint was trained"."""

from __future__ import annotations

import argparse

from neuraldem.scenes.fluidized_bed.surrogate.options import MAX_ROLLOUT_NOISE, check_rollout_value


def add_rollout_flags(p: argparse.ArgumentParser, *, correction: bool = True,
                      default: str = "as the checkpoint was trained") -> None:
    """--rollout-noise, --mirror-alternate and (with `correction`) --advection-correction."""
    p.add_argument("--rollout-noise", type=float, default=None,
                   help=f"the rollouts' rollout_noise, 0 .. {MAX_ROLLOUT_NOISE:g} times the one-step error "
                        f"(default: {default})")
    if correction:
        p.add_argument("--advection-correction", type=float, default=None,
                       help=f"the mixing advection's flux correction, 0 .. 1 (default: {default})")
    p.add_argument("--mirror-alternate", action="store_true", default=None,
                   help=f"every second step in the mirror image of the bed (default: {default})")


def check_rollout_flags(rollout_noise: float | None, advection_correction: float | None = None) -> None:
    """One line naming the flag for a value outside its range (None: as trained, always fine)."""
    if rollout_noise is not None:
        check_rollout_value("rollout_noise", rollout_noise, "--rollout-noise")
    if advection_correction is not None:
        check_rollout_value("advection_correction", advection_correction, "--advection-correction")
