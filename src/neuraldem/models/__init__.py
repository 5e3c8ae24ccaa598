"""Neural networks of NeuralDEM: the hopper field model and the multi-branch neural operator.

Reusable building blocks live in `neuraldem.models.modules`; `registry` builds a net from `conf/model/*.yaml`.
The nets are imported on first use, so that torch-free parts (the scalar baselines) load without torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_LAZY = {"HopperFieldModel": "neuraldem.models.hopper_field",
         "MultiBranchOperator": "neuraldem.models.multi_branch_operator",
         "OperatorInputs": "neuraldem.models.multi_branch_operator"}

__all__ = list(_LAZY)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'neuraldem.models' has no attribute {name!r}")
