"""Hopper metric functions on cases with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from neuraldem.eval import hopper_metrics as hm


def test_linear_drain_known_answers():
    # 100 points, 10 leave every 0.1 s until 20 remain
    times = np.arange(0, 1.5, 0.1)
    counts = np.maximum(100 - 100 * times, 20).round()
    occ = np.array([[q < c for q in range(100)] for c in counts])
    assert hm.residual_fraction(hm.occupied_counts(occ), 100) == pytest.approx(0.2)
    assert hm.drainage_time(times, counts, 100, margin=0.01) == pytest.approx(0.8)
    # 10 %..60 % of the drained 80 points leave at 100 points/s -> 1.0 of N0 per second
    assert hm.outflow_rate(times, counts, 100) == pytest.approx(1.0)


def test_nothing_drains():
    times = np.arange(5) * 0.1
    counts = np.full(5, 50.0)
    assert hm.outflow_rate(times, counts, 50) == 0.0
    assert hm.drainage_time(times, counts, 50) == 0.0
    assert hm.residual_fraction(counts, 50) == 1.0


def _stripes_case(order: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """4 layers of 10 points; layers leave one per snapshot in `order` (bottom = 0)."""
    z0 = np.repeat(np.arange(4) + 0.5, 10)
    T = 5
    occ = np.ones((T, 40), dtype=bool)
    for step, layer in enumerate(order, start=1):
        occ[step:, z0 == layer + 0.5] = False
    transport_z = np.tile(z0, (T, 1))
    return np.arange(T) * 1.0, occ, transport_z, z0


def test_mass_flow_index_first_in_first_out_vs_inversion():
    t, occ, tz, z0 = _stripes_case([0, 1, 2, 3])  # bottom first: mass flow
    stripes = hm.layer_stripes(occ, tz, hm.layer_edges(z0, 4))
    assert stripes[0].tolist() == [10, 10, 10, 10]
    assert hm.mass_flow_index(t, stripes) == pytest.approx(1.0)
    assert hm.flow_regime(hm.mass_flow_index(t, stripes)) == "mass"
    t, occ, tz, z0 = _stripes_case([3, 2, 1, 0])  # top first: full inversion
    assert hm.mass_flow_index(t, hm.layer_stripes(occ, tz, hm.layer_edges(z0, 4))) == pytest.approx(-1.0)


def test_layers_that_never_empty_count_as_last():
    t, occ, tz, z0 = _stripes_case([3, 2])  # top two leave, bottom two stay (dead zone)
    index = hm.mass_flow_index(t, hm.layer_stripes(occ, tz, hm.layer_edges(z0, 4)))
    assert index < -0.5
    assert hm.flow_regime(index) == "funnel"
