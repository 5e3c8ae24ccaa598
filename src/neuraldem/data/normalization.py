"""Scaling between physical units and the model's unit ranges, fitted on the training split only.

Positions map the scene box to [0, 1]^3; scalars map their training range to [0, 1]; times map
[0, horizon] to [0, 1]. The stats travel inside every checkpoint, so a model is always evaluated with the
scaling it was trained with.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Self

import numpy as np

from neuraldem.errors import DataError


class OutsideBoxError(DataError):
    """Query points far outside the box a model was trained on: that run cannot be answered (others can)."""


class DictStats:
    """`to_dict` / `from_dict` of a dataclass of fitted statistics: the plain dict travels inside every
    checkpoint, and the same dict builds the normalizer again."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)  # type: ignore[call-overload]  # every user is a dataclass

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Self:
        return cls(**d)


def scaled_scalar(values: dict[str, float], name: str, lo: dict[str, float], hi: dict[str, float]) -> float:
    """One conditioning scalar mapped from its training range to [0, 1] (0.5 where training saw one value);
    a missing one is an error that says how to record it."""
    if name not in values:
        raise DataError(f"conditioning scalar {name!r} is not available (have {sorted(values)}); "
                        "macroscopic scalars need datagen with data.characterization.enabled=true")
    low, high = lo[name], hi[name]
    return (values[name] - low) / (high - low) if high > low else 0.5


@dataclass
class HopperNormalizer(DictStats):
    box_lo: list[float]  # scene box [m], 3 values
    box_hi: list[float]
    horizon: float  # [s] time range covered; particles that never leave get this as exit time
    scalar_lo: dict[str, float] = field(default_factory=dict)
    scalar_hi: dict[str, float] = field(default_factory=dict)

    # ---- positions
    def positions(self, x: np.ndarray) -> np.ndarray:
        lo, hi = np.asarray(self.box_lo), np.asarray(self.box_hi)
        return (x - lo) / (hi - lo)

    def positions_back(self, u: np.ndarray) -> np.ndarray:
        lo, hi = np.asarray(self.box_lo), np.asarray(self.box_hi)
        return lo + np.asarray(u) * (hi - lo)

    def check_inside(self, x: np.ndarray, what: str, tol: float = 1e-6) -> None:
        """Query points outside the box the model was trained on are an error, not a silent extrapolation."""
        u = self.positions(np.asarray(x))
        bad = ~np.all((u >= -tol) & (u <= 1 + tol), axis=-1)
        if bad.any():
            worst = np.asarray(x)[bad][0]
            raise OutsideBoxError(f"{what}: {int(bad.sum())} query point(s) outside the scene box "
                            f"{np.round(self.box_lo, 4).tolist()} .. {np.round(self.box_hi, 4).tolist()} m "
                            f"the model was trained on (e.g. {np.round(worst, 4).tolist()}); "
                            "drop or clip them before querying")

    # ---- time and scalars
    def time(self, t: np.ndarray | float) -> np.ndarray:
        return np.asarray(t, dtype=np.float64) / self.horizon

    def time_back(self, u: np.ndarray | float) -> np.ndarray:
        return np.asarray(u, dtype=np.float64) * self.horizon

    def outside_range(self, values: dict[str, float], names: list[str]) -> dict[str, list[float]]:
        """The conditioning scalars outside the range seen in training: {name: [value, lo, hi]}. A model
        still answers there, but the answer is an extrapolation and must be flagged as one."""
        out = {}
        for name in names:
            if name == "t" or name not in values or name not in self.scalar_lo:
                continue
            lo, hi, v = self.scalar_lo[name], self.scalar_hi[name], float(values[name])
            if v < lo - 1e-9 * max(1.0, abs(lo)) or v > hi + 1e-9 * max(1.0, abs(hi)):
                out[name] = [v, lo, hi]
        return out

    def scalars(self, values: dict[str, float], names: list[str], t: float) -> np.ndarray:
        out = []
        for name in names:
            if name == "t":
                out.append(float(self.time(t)))
                continue
            out.append(scaled_scalar(values, name, self.scalar_lo, self.scalar_hi))
        return np.asarray(out, dtype=np.float32)
