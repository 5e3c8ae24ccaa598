"""Neural networks of NeuralDEM: the hopper field model and the multi-branch neural operator.

Reusable building blocks live in `neuraldem.models.modules`; `registry` builds a net from `conf/model/*.yaml`.
"""

from neuraldem.models.hopper_field import HopperFieldModel
from neuraldem.models.multi_branch_operator import MultiBranchOperator, OperatorInputs

__all__ = ["HopperFieldModel", "MultiBranchOperator", "OperatorInputs"]
