"""Refill metrics on hand-made synthetic inputs (labels, fractions, residence samples chosen by hand)."""

from __future__ import annotations

import numpy as np
import pytest

from neuraldem.scenes.hopper_refill.metrics import (
    EMPTY,
    NEW,
    fraction_error,
    label_agreement,
    layer_fractions,
    layer_labels,
    outlet_region,
    particle_exit_residence,
    reference_layer_edges,
    rtd_scores,
)


def test_layers_by_reference_height_and_new_material():
    edges = reference_layer_edges(np.linspace(0.0, 0.4, 101), n_layers=4)  # evenly spread: layers 0.1 m thick
    np.testing.assert_allclose(edges, [0.0, 0.1, 0.2, 0.3, 0.4])
    # equal shares: two stragglers far above do not stretch the layers of a bed between 0 and 0.4 m
    bed = np.concatenate([np.linspace(0.0, 0.4, 998), [2.0, 3.0]])
    assert reference_layer_edges(bed, n_layers=4)[3] == pytest.approx(0.3, abs=0.002)
    occupied = np.array([True, True, True, True, False])
    transport_z = np.array([0.05, 0.15, 0.39, np.nan, np.nan])
    new = np.array([False, False, False, True, False])
    labels = layer_labels(occupied, transport_z, new, edges)
    assert labels.tolist() == [0, 1, 3, NEW, EMPTY]
    np.testing.assert_allclose(layer_fractions(labels, 4), [0.25, 0.25, 0.0, 0.25, 0.25])


def test_fraction_error_and_agreement():
    assert fraction_error([0.5, 0.5, 0.0], [0.5, 0.5, 0.0]) == 0.0
    assert fraction_error([1.0, 0.0], [0.0, 1.0]) == 1.0
    truth = np.array([0, 1, NEW, EMPTY])
    assert label_agreement(truth, np.array([0, 2, NEW, 0])) == pytest.approx(2 / 3)


def test_outlet_region_and_particle_rtd():
    pts = np.array([[0.0, 0.0, 0.01], [0.03, 0.0, 0.01], [0.0, 0.0, -0.01], [0.0, 0.0, 0.05]])
    assert outlet_region(pts, outlet_radius=0.02, height=0.04).tolist() == [True, False, False, False]
    res = particle_exit_residence(np.array([1.0, np.nan, 3.0]), np.array([0.5, 0.0, 1.0]), t_from=0.0, t_to=2.0)
    assert res.tolist() == [0.5]


def test_rtd_scores():
    a = np.array([1.0, 2.0, 3.0])
    assert rtd_scores(a, a)["rtd_wasserstein_s"] == 0.0
    s = rtd_scores(a, a + 0.5)
    assert s["rtd_wasserstein_s"] == pytest.approx(0.5) and s["rtd_median_error_s"] == pytest.approx(0.5)
    assert np.isnan(rtd_scores(a, np.zeros(0))["rtd_wasserstein_s"])
