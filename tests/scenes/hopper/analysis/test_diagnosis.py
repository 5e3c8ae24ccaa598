"""The hopper diagnosis names the field an answer's error comes from (known answers on constructed fields), reads
fractions of N0 and of the fill as defined, and never reads test runs."""

from __future__ import annotations

import numpy as np
import pytest

from neuraldem.errors import ConfigError
from neuraldem.scenes.hopper.analysis import diagnosis
from neuraldem.scenes.hopper.analysis import metrics as hm

S = hm.HopperMetricSettings()


def _mass_flow(n_layers: int = 4, per_layer: int = 10) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Layers leave one per snapshot from the bottom (first in, first out): index +1."""
    z0 = np.repeat(np.arange(n_layers) + 0.5, per_layer)
    times = np.arange(n_layers + 1) * 1.0
    occ = np.ones((len(times), len(z0)))
    for step in range(1, n_layers + 1):
        occ[step:, z0 == step - 0.5] = 0.0
    return times, occ, z0


def test_a_scrambled_transport_field_is_named_as_the_cause():
    times, occ, z0 = _mass_flow()
    solver_z = np.tile(z0, (len(times), 1))
    scrambled = np.tile(z0[::-1], (len(times), 1))  # the model says the bottom material came from the top
    index = diagnosis.index_swaps(times, {"model": occ, "solver": occ}, {"model": scrambled, "solver": solver_z},
                                  z0, hm.HopperMetricSettings(n_layers=4))
    assert index["solver"] == pytest.approx(1.0)
    assert index["model occupancy, solver transport"] == pytest.approx(1.0)  # the occupancy is right
    assert index["model"] == pytest.approx(-1.0) == index["solver occupancy, model transport"]
    err = diagnosis.transport_error(scrambled, solver_z, occ, z0, 4)
    assert err["median_abs_dz_layers"] > 0.5 and err["share_over_half_layer"] == pytest.approx(1.0)
    assert diagnosis.transport_error(solver_z, solver_z, occ, z0, 4)["median_abs_dz_layers"] == 0.0


def test_fractions_of_the_fill_read_a_uniformly_soft_field_as_the_sharp_one():
    times = hm.metric_times(4.0, 0.05)
    leave = np.linspace(0.2, 2.2, 400)
    leave[:40] = np.inf
    sharp = (times[:, None] < leave[None, :]).astype(float)
    truth, soft = diagnosis.fill_readings(times, sharp, S), diagnosis.fill_readings(times, 0.98 * sharp, S)
    assert truth["fill_share"] == 1.0 and soft["fill_share"] == pytest.approx(0.98)
    assert truth["outflow_rate_n0"] == truth["outflow_rate_fill"]
    assert soft["outflow_rate_fill"] == pytest.approx(truth["outflow_rate_fill"], rel=1e-12)
    assert soft["outflow_rate_n0"] == pytest.approx(0.98 * truth["outflow_rate_n0"], rel=1e-12)
    assert soft["residual_fraction_fill"] == pytest.approx(0.1) and soft["residual_fraction_n0"] == pytest.approx(0.098)
    rows = [{"mass_flow_index": {"solver": 1.0, **{k: 1.0 for k in diagnosis.SWAPS}},
             "solver": {"outflow_rate": truth["outflow_rate_fill"], "residual_fraction": 0.1}, "model": soft,
             "transport": {"median_abs_dz_layers": 0.0, "share_over_half_layer": 0.0}}]
    summary = diagnosis.summarise(rows, 0.5)["fractions_of"]
    assert list(summary) == ["model"]  # no what-if answers in these rows
    assert summary["model"]["fill_share"] == pytest.approx(0.98)
    assert summary["model"]["fill"]["outflow_bias_pct"] == pytest.approx(0.0, abs=1e-9)
    assert summary["model"]["n0"]["outflow_bias_pct"] == pytest.approx(-2.0)
    assert summary["model"]["n0"]["outflow_runs_under"] == 1


def test_the_test_runs_are_not_read():
    with pytest.raises(ConfigError, match="part='test' is invalid.*read once, by neuraldem release"):
        diagnosis.run("hopper_small", None, "test", None)
