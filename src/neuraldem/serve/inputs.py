"""Typed parameter values: parsed, kept within what the solver can run, and said so on the page.

Sliders span the model's trained range; a typed value may go beyond it (an extrapolation the page warns
about, as `neuraldem predict` does) but not beyond the solver's limits: such a value is clamped to the
limit with a visible note, instead of an error that would leave the page on the old answer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

NEAR = 0.05  # a stored solver run is shown when every parameter is within 5 % of its trained range
DECIMALS = 6  # parameter values are rounded so a slider's 38.50000000000001 and a typed 38.5 are one point


@dataclass(frozen=True)
class TypedValue:
    value: float | None  # None: not a number (the page keeps its previous value)
    note: str  # empty when the value was taken as typed


def parameter_value(value: float) -> float:
    return round(float(value), DECIMALS)


def typed_value(name: str, text: str | float, limits: tuple[float, float]) -> TypedValue:
    """`text` as a value of parameter `name` within the solver's `limits` (clamped, with a note)."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        return TypedValue(None, f"{name}: {text!r} is not a number; the previous value is kept")
    if not math.isfinite(value):
        return TypedValue(None, f"{name}: {text!r} is not a finite number; the previous value is kept")
    lo, hi = limits
    clamped = min(max(value, lo), hi)
    if clamped != value:
        return TypedValue(parameter_value(clamped), f"{name}={value:g} is outside what the solver can run "
                                                    f"({lo:g} .. {hi:g}): clamped to {clamped:g}")
    return TypedValue(parameter_value(value), "")
