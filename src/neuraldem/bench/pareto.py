"""The Pareto front of (cost, error) points: the choices a user should pick from, everything else is beaten."""

from __future__ import annotations

import math
from collections.abc import Sequence


def dominates(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """`a` is at least as cheap and as accurate as `b`, and strictly better in one of the two."""
    return a[0] <= b[0] and a[1] <= b[1] and (a[0] < b[0] or a[1] < b[1])


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the points no other point dominates (lower is better on both axes), sorted by cost.

    Points with a NaN coordinate (a failed method) are never on the front and never beat anything.
    Identical points are all on the front. Quadratic in the number of points: charts have tens of them."""
    valid = [i for i, p in enumerate(points) if not any(math.isnan(v) for v in p)]
    front = [i for i in valid if not any(dominates(points[j], points[i]) for j in valid if j != i)]
    return sorted(front, key=lambda i: (points[i][0], points[i][1], i))
