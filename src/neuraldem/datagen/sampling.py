"""Seeded Latin-hypercube sampling of simulation parameters, extendable batch by batch.

Extending a dataset (more simulations later) adds a new Latin-hypercube batch drawn with its own seed,
so finished simulations keep their parameters and the union stays well spread.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import qmc


def latin_hypercube(ranges: dict[str, tuple[float, float]], n: int, seed: int, batch: int) -> list[dict[str, float]]:
    if n <= 0:
        return []
    names = list(ranges)
    sampler = qmc.LatinHypercube(d=len(names), rng=np.random.default_rng([seed, batch]))
    unit = sampler.random(n)
    lo = np.array([ranges[k][0] for k in names])
    hi = np.array([ranges[k][1] for k in names])
    values = qmc.scale(unit, lo, hi) if np.all(hi > lo) else lo + unit * (hi - lo)
    return [{k: round(float(v), 6) for k, v in zip(names, row, strict=False)} for row in values]
