"""The Pareto front on hand-made point sets with known answers."""

from __future__ import annotations

import math

from neuraldem.bench.pareto import dominates, pareto_front


def test_known_front():
    points = [
        (1.0, 50.0),   # 0: fastest -> front
        (2.0, 60.0),   # 1: slower and worse than 0 -> dominated
        (3.0, 10.0),   # 2: front
        (3.0, 20.0),   # 3: same time as 2, worse -> dominated
        (10.0, 10.0),  # 4: same error as 2, slower -> dominated
        (100.0, 1.0),  # 5: most accurate -> front
        (0.5, 99.0),   # 6: fastest of all -> front
    ]
    assert pareto_front(points) == [6, 0, 2, 5]  # sorted by time


def test_nan_points_are_never_on_the_front_and_beat_nothing():
    points = [(1.0, math.nan), (2.0, 5.0), (math.nan, 0.0)]
    assert pareto_front(points) == [1]


def test_identical_points_are_both_on_the_front():
    assert pareto_front([(1.0, 1.0), (1.0, 1.0), (2.0, 2.0)]) == [0, 1]
    assert not dominates((1.0, 1.0), (1.0, 1.0))
    assert dominates((1.0, 1.0), (1.0, 2.0))


def test_empty():
    assert pareto_front([]) == []
