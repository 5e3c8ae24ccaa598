"""A bed model read without its LightningModule (`step_model`) rolls out exactly as the LightningModule does: the
recipe's options (solids flux, advected mixing, volume projection, a stochastic net, rollout noise from the running
one-step error) and the shipped model, bit for bit; and a checkpoint of another kind is refused by name."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neuraldem.errors import DataError
from neuraldem.eval.checkpoints import read_checkpoint
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.options import RolloutOptions
from neuraldem.scenes.fluidized_bed.surrogate.rollout import ModelStepper, initial_state, rollout
from neuraldem.scenes.fluidized_bed.surrogate.step_model import read_step_model

TRAINED_VELOCITY = 1.228531


def _same_rollouts(checkpoint: Path, state, velocity: float, steps: int, **stepper) -> None:
    read = read_checkpoint(checkpoint)
    runs = [rollout(ModelStepper(m, velocity, 3, **stepper), state, steps, progress=False)
            for m in (read.module("fluidized_bed", "cpu", "test"), read_step_model(read, "cpu", "test"))]
    assert runs[0].steps_done == steps
    for name in ("solid_fraction", "fluid_velocity", "mixing", "positions", "displacement"):
        np.testing.assert_array_equal(getattr(runs[0], name), getattr(runs[1], name), err_msg=name)


def test_the_recipe_options_and_rollout_noise_step_alike(fb_tiny_flux_checkpoint: Path, fb_tiny_dataset: Path):
    step_model = read_step_model(read_checkpoint(fb_tiny_flux_checkpoint))
    assert step_model.stability.mixing == "advect" and step_model.net.noise_dim == 4
    assert float(step_model.step_error_fluid.abs().sum()) > 0  # what rollout_noise scales
    with BedFile(sorted((fb_tiny_dataset / "sims").glob("*.h5"))[0]) as f:
        state = initial_state(f)
    _same_rollouts(fb_tiny_flux_checkpoint, state, TRAINED_VELOCITY, 12,
                   options=RolloutOptions(rollout_noise=2.0, mirror_alternate=True), runtime="torch")


def test_the_shipped_model_steps_alike_in_both_runtimes():
    from neuraldem import pretrained
    from neuraldem.scenes.fluidized_bed.whatif import InitialStates

    model = pretrained.load("fb_small", "fluidized_bed")
    state, _, _ = InitialStates.load_npz(model.file("states")).nearest(1.7)
    for runtime in ("torch", "onnx"):
        _same_rollouts(model.file("field"), state, 1.7, 15, runtime=runtime)


def test_a_checkpoint_of_another_kind_is_refused(tiny_checkpoint: Path):
    with pytest.raises(DataError, match="is a 'hopper' checkpoint .* needs a fluidized_bed model: train one"):
        read_step_model(read_checkpoint(tiny_checkpoint), purpose="a what-if")
