"""Hopper metric functions on synthetic curves with known answers, and their robustness to small field errors."""

from __future__ import annotations

import numpy as np
import pytest

from neuraldem.errors import ConfigError
from neuraldem.scenes.hopper.analysis import metrics as hm

S = hm.HopperMetricSettings()


def _linear_drain(n0: int = 1000, rate: float = 500.0, residue: int = 200, horizon: float = 5.0,
                  dt: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Counts falling at `rate` points/s from n0 until `residue` remain, then constant to the horizon."""
    times = hm.metric_times(horizon, dt)
    return times, np.maximum(n0 - rate * times, residue)


def test_linear_drain_known_answers():
    times, counts = _linear_drain()  # 800 points leave at 500/s: the drain ends at 1.6 s
    assert hm.final_level(times, counts, S.tail_time) == 200
    assert hm.residual_fraction(times, counts, 1000, S.tail_time) == pytest.approx(0.2)
    assert hm.drainage_t95(times, counts, S.tail_time) == pytest.approx(0.95 * 1.6)
    # secondary rule: within 1 % of N0 (10 points) of the final level: 790 / 500 s
    assert hm.drainage_time(times, counts, 1000, S.tail_time) == pytest.approx(1.6)
    assert hm.outflow_rate(times, counts, 1000, S.tail_time, S.outflow_window) == pytest.approx(0.5)


def test_t95_interpolates_between_snapshots():
    times, counts = _linear_drain(rate=517.0)
    assert hm.drainage_t95(times, counts, S.tail_time) == pytest.approx(0.95 * 800 / 517.0, abs=1e-9)


def test_nothing_drains():
    times = hm.metric_times(2.0, 0.1)
    counts = np.full(len(times), 50.0)
    assert hm.outflow_rate(times, counts, 50, S.tail_time) == 0.0
    assert hm.drainage_t95(times, counts, S.tail_time) == 0.0
    assert hm.drainage_time(times, counts, 50, S.tail_time) == 0.0
    assert hm.residual_fraction(times, counts, 50, S.tail_time) == 1.0


def test_small_decaying_tail_moves_t95_and_residual_little():
    """A model that leaves 2 % of N0 decaying slowly over the rest of the range: the 1 %-rule drainage time
    moves towards the end of the range, t95 and the tail-mean residual hardly move."""
    times, counts = _linear_drain(residue=0, horizon=10.0)  # drains completely at 2.0 s
    tail = 20.0 * np.exp(-np.clip(times - 2.0, 0, None) / 4.0) * (times >= 2.0)  # 2 % of N0, slow decay
    noisy = np.maximum(counts, tail)
    t95_clean, t95_noisy = (hm.drainage_t95(times, c, S.tail_time) for c in (counts, noisy))
    assert abs(t95_noisy - t95_clean) / t95_clean < 0.03
    assert abs(hm.residual_fraction(times, noisy, 1000, S.tail_time) - 0.0) < 0.005  # < 0.5 pp
    assert hm.drainage_time(times, noisy, 1000, S.tail_time) > 1.5 * hm.drainage_time(times, counts, 1000,
                                                                                       S.tail_time)
    out_clean, out_noisy = (hm.outflow_rate(times, c, 1000, S.tail_time, S.outflow_window) for c in (counts, noisy))
    assert abs(out_noisy - out_clean) / out_clean < 0.03


def test_soft_counts_of_a_smoothed_field_match_the_truth():
    """Points leave one by one; a 'model' that smears each point's 0 -> 1 step over a few snapshots (symmetric
    ramp) keeps the soft count, so t95 and outflow stay within a snapshot of the truth, while a 0.5 threshold
    of a field biased by 0.1 towards occupied would not."""
    times = hm.metric_times(4.0, 0.05)
    leave = np.linspace(0.2, 2.2, 400)  # when each of 400 points empties
    truth = (times[:, None] < leave[None, :]).astype(float)
    smooth = 1.0 / (1.0 + np.exp(-(leave[None, :] - times[:, None]) / 0.05))
    st = hm.hopper_summary(times, truth, np.zeros_like(truth), np.zeros(400))
    sp = hm.hopper_summary(times, smooth, np.zeros_like(truth), np.zeros(400))
    assert abs(sp["drainage_t95"] - st["drainage_t95"]) < 0.05
    assert abs(sp["outflow_rate"] - st["outflow_rate"]) / st["outflow_rate"] < 0.02
    assert abs(sp["residual_fraction"] - st["residual_fraction"]) < 0.005


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


def test_soft_stripes_weight_by_probability():
    t, occ, tz, z0 = _stripes_case([0, 1, 2, 3])
    stripes = hm.layer_stripes(0.5 * occ, tz, hm.layer_edges(z0, 4))
    assert stripes[0].tolist() == [5, 5, 5, 5]
    assert hm.mass_flow_index(t, stripes) == pytest.approx(1.0)


def test_layers_that_never_empty_count_as_last():
    t, occ, tz, z0 = _stripes_case([3, 2])  # top two leave, bottom two stay (dead zone)
    index = hm.mass_flow_index(t, hm.layer_stripes(occ, tz, hm.layer_edges(z0, 4)))
    assert index < -0.5
    assert hm.flow_regime(index) == "funnel"


def test_settings_are_validated_with_the_key():
    assert hm.HopperMetricSettings.from_config({"tail_time": 0.5}).tail_time == 0.5
    with pytest.raises(ConfigError, match=r"data\.metrics\.outflow_window"):
        hm.HopperMetricSettings.from_config({"outflow_window": [0.7, 0.2]})
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['drain_margn'\]"):
        hm.HopperMetricSettings.from_config({"drain_margn": 0.01})
    with pytest.raises(ConfigError, match=r"data\.metrics\.drain_fraction"):
        hm.HopperMetricSettings.from_config({"drain_fraction": 1.5})
    s = hm.HopperMetricSettings.from_config(hm.HopperMetricSettings().as_dict())
    assert s == hm.HopperMetricSettings()  # round trip through the manifest's record


def test_the_mass_flow_index_equals_scipys_spearman_bit_for_bit():
    """The index ranks without scipy.stats (a second of import time on the what-if path): same float as scipy."""
    from scipy.stats import spearmanr

    from neuraldem.scenes.hopper.analysis.metrics import average_ranks

    rng = np.random.default_rng(0)
    for _ in range(2000):
        n = int(rng.integers(2, 16))
        h = np.round(rng.random(n) * rng.integers(1, 6), 1)
        h[rng.random(n) < 0.2] = np.inf
        if np.all(h == h[0]):
            continue
        ranks = np.column_stack([average_ranks(np.arange(n)), average_ranks(h)])
        assert float(np.corrcoef(ranks, rowvar=False)[1, 0]) == float(spearmanr(np.arange(n), h).statistic)
