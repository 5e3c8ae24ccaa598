"""Heap test (angle of repose): flank fit on synthetic heaps, settings validation, friction trend."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from neuraldem.errors import ConfigError
from neuraldem.sim.heap import HeapSettings, fit_heap, run_heap_test
from neuraldem.sim.material import Material

KEY = "data.characterization.heap"
D = 0.01


def _cone(angle_deg: float, height_d: float, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """Particle tops filling a cone of the given slope on a one-particle base layer (units: m)."""
    x, y = np.meshgrid(np.arange(-30, 30.5, 0.5), np.arange(-30, 30.5, 0.5))
    x, y = x.ravel() + rng.uniform(-0.2, 0.2, x.size), y.ravel() + rng.uniform(-0.2, 0.2, x.size)
    r = np.hypot(x, y)
    top = np.maximum(height_d - r * math.tan(math.radians(angle_deg)), 0.0) + 1.0  # + base layer
    return x * D, y * D, top * D


# ---------------------------------------------------------------- flank fit (no solver)
@pytest.mark.parametrize("angle", [10.0, 25.0, 35.0])
def test_fit_recovers_the_slope_of_a_cone(angle: float) -> None:
    x, y, top = _cone(angle, 8.0, np.random.default_rng(0))
    fit = fit_heap(x, y, top, D, HeapSettings())
    assert fit["heap_formed"] and fit["n_fit"] >= 3
    assert fit["repose_deg"] == pytest.approx(angle, abs=2.0)
    assert fit["heap_height"] == pytest.approx(8.0, abs=0.6)
    assert fit["fit_r2"] > 0.95


def test_spread_layer_gives_a_small_finite_angle() -> None:
    """No heap (one or two layers): the aspect-angle fallback, finite and near zero, never NaN."""
    rng = np.random.default_rng(1)
    x, y = rng.uniform(-25, 25, 2000), rng.uniform(-25, 25, 2000)
    top = np.where(rng.uniform(size=2000) < 0.1, 1.8, 1.0)  # a few particles on top of the first layer
    fit = fit_heap(x * D, y * D, top * D, D, HeapSettings())
    assert not fit["heap_formed"]
    assert math.isfinite(fit["repose_deg"]) and 0.0 <= fit["repose_deg"] < 3.0
    flat = fit_heap(x * D, y * D, np.ones_like(x) * D, D, HeapSettings())
    assert flat["repose_deg"] == 0.0 and not flat["heap_formed"]
    gone = fit_heap(np.array([]), np.array([]), np.array([]), D, HeapSettings())  # all rolled away
    assert gone["repose_deg"] == 0.0 and not gone["heap_formed"]


# ---------------------------------------------------------------- settings (no solver)
def test_presets_are_valid() -> None:
    HeapSettings().validate(KEY)
    HeapSettings.tiny().validate(KEY)
    assert HeapSettings.from_config({"preset": "tiny"}, KEY) == HeapSettings.tiny()
    s = HeapSettings.from_config({"fit_band": [0.3, 0.7]}, KEY)
    assert s.fit_band == (0.3, 0.7)


@pytest.mark.parametrize("field, value", [
    ("lift_height", 3.0),  # does not clear the fill of 2000 particles
    ("lift_speed", -0.05),
    ("tube_radius", 1.0),
    ("domain_half_width", 10.0),  # smaller than two tube radii
    ("fit_band", [0.8, 0.2]),
    ("fit_band", [0.2, 1.5]),
    ("seed", 15),
    ("n_particles", 0),
])
def test_out_of_range_settings_name_the_key(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=rf"{KEY}\.{field}"):
        HeapSettings.from_config({field: value}, KEY)


# ---------------------------------------------------------------- physics (tiny preset)
@pytest.mark.solver
def test_repose_rises_with_friction(tmp_path: Path) -> None:
    """Tiny preset, measured: mu_s/mu_r 1.0/0.5 -> 26-34 deg, 0.1/0.05 -> 0 deg (no heap, spread layer).
    The small preset gives 36 deg and 1.8 deg."""
    settings = HeapSettings.tiny()
    high = run_heap_test(Material(mu_s=1.0, mu_r=0.5), settings, tmp_path / "high")
    low = run_heap_test(Material(mu_s=0.1, mu_r=0.05), settings, tmp_path / "low")
    assert high.heap_formed and high.repose_deg > 20.0 and high.n_fit >= 3
    assert not low.heap_formed
    assert math.isfinite(low.repose_deg) and 0.0 <= low.repose_deg < 6.0
    assert high.repose_deg > low.repose_deg + 15.0, (high.repose_deg, low.repose_deg)
    assert high.n_lost == 0 and high.cpu_s > 0
    assert (tmp_path / "high" / "tube.stl").exists() and (tmp_path / "high" / "in.heap").exists()
