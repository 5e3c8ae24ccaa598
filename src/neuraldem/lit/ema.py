"""An exponential moving average (EMA) of the weights, validated, for `callbacks.ema`.

Why: a rollout compounds the small step-to-step jitter of the weights the optimizer happens to stop at; the
average over the last few hundred steps is the smoother map. Lightning's `EMAWeightAveraging` keeps the average
beside the training weights (training itself is unchanged: the raw weights of a run with and without it are
bit-identical), swaps it in for every validation (so the rollout validation scores and selects the averaged
model) and writes it as the checkpoint's `state_dict`, with the optimizer's weights kept as
`current_model_state` (`python -m neuraldem.eval.current_weights src=... dst=...` writes those as a checkpoint of
their own).
"""

from __future__ import annotations

from lightning.pytorch.callbacks import EMAWeightAveraging

from neuraldem.config import checks

KEY = "callbacks.ema"


class Ema(EMAWeightAveraging):
    """`decay` per optimizer step (0.995: the average spans ~200 steps), from step `update_starting_at_step`
    (after the learning-rate warm-up: the first steps' weights are far from the rest), every
    `update_every_n_steps` steps."""

    def __init__(self, decay: float = 0.995, update_starting_at_step: int = 200, update_every_n_steps: int = 1):
        checks.number(f"{KEY}.decay", decay, lo=0.0, hi=1.0, lo_open=True, hi_open=True)
        checks.positive_int(f"{KEY}.update_starting_at_step", update_starting_at_step, allow_zero=True)
        checks.positive_int(f"{KEY}.update_every_n_steps", update_every_n_steps)
        super().__init__(decay=float(decay), update_every_n_steps=update_every_n_steps,
                         update_starting_at_step=update_starting_at_step)
