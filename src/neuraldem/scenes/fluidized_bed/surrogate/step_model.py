"""What a rollout reads from a trained bed model, read from its checkpoint without building the LightningModule.

Why: a what-if (`neuraldem predict fluidized_bed`, the explorer) only steps the model. Building its
`BedModule` imports Lightning, ~1.3 s of a one-off answer on a 2-core CPU (`python -X importtime`), for
nothing a rollout uses. `ModelStepper` takes either: both carry the net, the normaliser, the stability options,
the metadata, the decoding chunk size, a residual model's step scales and the running one-step error that
`rollout_noise` scales. `tests/scenes/fluidized_bed/surrogate/test_step_model.py` checks that a rollout of one
equals a rollout of the other bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from neuraldem.eval.checkpoints import Checkpoint, checkpoint_net
from neuraldem.models.multi_branch_operator import MultiBranchOperator
from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import grid_step_scales
from neuraldem.scenes.fluidized_bed.surrogate.normalization import BedNormalizer
from neuraldem.scenes.fluidized_bed.surrogate.options import BedStability

KIND = "fluidized_bed"


@dataclass(frozen=True)
class BedStepModel:
    net: MultiBranchOperator
    norm: BedNormalizer
    stability: BedStability
    metadata: dict[str, Any]
    chunk_size: int | None
    step_scales: dict[str, torch.Tensor] | None
    step_error_particles: torch.Tensor
    step_error_fluid: torch.Tensor
    step_error_mixing: torch.Tensor


def read_step_model(checkpoint: Checkpoint, device: str = "cpu", purpose: str = "this command") -> BedStepModel:
    """The parts of a bed checkpoint a rollout reads (`BedModule`'s, without it); a checkpoint of another kind is
    refused with the command that trains one. A checkpoint from before the running one-step error holds it at
    zero, as `BedModule.on_load_checkpoint` loads it."""
    net = checkpoint_net(checkpoint, KIND, device, purpose)
    hp = checkpoint.hyper_parameters
    metadata = hp["metadata"]
    norm = BedNormalizer.from_dict(metadata["normalizer"])
    state = checkpoint.raw["state_dict"]
    channels = {"particles": net.channels["particles"],
                "fluid": int(metadata.get("grid_channels", hp["net"].get("fluid_channels", 4))), "mixing": 1}
    errors = {name: state.get(f"step_error_{name}", torch.zeros(c)).to(device) for name, c in channels.items()}
    return BedStepModel(
        net=net, norm=norm, stability=BedStability.from_config(hp.get("stability")), metadata=metadata,
        chunk_size=hp.get("chunk_size"), step_scales=grid_step_scales(norm) if hp.get("residual") else None,
        step_error_particles=errors["particles"], step_error_fluid=errors["fluid"],
        step_error_mixing=errors["mixing"])
