"""SYNTHETIC STAND-IN for a solver: the dynamic angle of repose of a rotating drum in closed form (a made-up
smooth function of speed and friction). It exists so that the plug-in machinery can be tested without a
solver binary."""

from __future__ import annotations

import math


def dynamic_repose_deg(speed: float, friction: float) -> float:
    return 20.0 + 25.0 * math.tanh(friction) + 0.15 * speed
