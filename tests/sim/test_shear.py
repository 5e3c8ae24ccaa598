"""Shear test (internal friction angle theta): settings, solver failures, rolling-friction trend."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from neuraldem.errors import ConfigError, SolverError
from neuraldem.sim.material import Material
from neuraldem.sim.shear import ShearResult, ShearSettings, fit_yield_locus, run_shear_test

KEY = "data.characterization.shear"


# ---------------------------------------------------------------- settings (no solver)
def test_presets_are_valid_and_tiny_is_cheaper() -> None:
    small, tiny = ShearSettings(), ShearSettings.tiny()
    small.validate(KEY)
    tiny.validate(KEY)
    def cost(s: ShearSettings) -> float:  # particle-steps of the shear stage, up to a constant
        return s.n_particles * s.strain / s.inertial_number

    assert cost(tiny) < cost(small) / 10


def test_from_config_preset_and_overrides() -> None:
    s = ShearSettings.from_config({"preset": "tiny", "normal_stress": 1500.0}, KEY)
    assert s == ShearSettings(**{**ShearSettings.tiny().as_dict(), "normal_stress": 1500.0})
    assert ShearSettings.from_config({}, KEY) == ShearSettings()
    assert ShearSettings.from_config(None, KEY) == ShearSettings()


@pytest.mark.parametrize("field, value", [
    ("normal_stress", -1.0),
    ("inertial_number", 0.0),
    ("strain", 0),
    ("average_from", 4.0),  # not below the total strain
    ("n_particles", 2.5),
    ("seed", 49979688),  # not a prime
    ("seed", 9973),  # a prime, but LIGGGHTS wants > 10000
    ("average_steps", 55),
    ("box_size", 2.0),
])
def test_out_of_range_settings_name_the_key(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=rf"{KEY}\.{field}"):
        ShearSettings.from_config({field: value}, KEY)


def test_too_few_particles_for_a_sheared_layer() -> None:
    with pytest.raises(ConfigError, match=rf"{KEY}\.n_particles.*layer"):
        ShearSettings.from_config({"n_particles": 200}, KEY)


def test_unknown_key_and_preset() -> None:
    with pytest.raises(ConfigError, match="normal_stres"):
        ShearSettings.from_config({"normal_stres": 3000.0}, KEY)
    with pytest.raises(ConfigError, match=rf"{KEY}\.preset"):
        ShearSettings.from_config({"preset": "huge"}, KEY)


def _result(sigma: float, tau: float) -> ShearResult:
    return ShearResult(theta_deg=math.degrees(math.atan(tau / sigma)), theta_err_deg=0.1, theta_top_deg=0.0,
                       theta_bottom_deg=0.0, mohr_coulomb_deg=0.0, normal_stress=sigma,
                       normal_stress_measured=sigma, shear_stress=tau, solid_fraction=0.6, dilation=0.0,
                       layer_height=10.0, shear_velocity=0.1, n_particles=1500, n_sheared=1200, n_lost=0,
                       cpu_s=1.0, wall_s=1.0)


def test_yield_locus_of_a_cohesive_and_a_cohesionless_line() -> None:
    mu = math.tan(math.radians(25.0))
    free = fit_yield_locus([_result(s, mu * s) for s in (1500.0, 3000.0, 6000.0)])
    assert abs(free.angle_deg - 25.0) < 1e-9 and abs(free.cohesion) < 1e-6
    assert free.unconfined_yield_strength < 1e-6
    sticky = fit_yield_locus([_result(s, 200.0 + mu * s) for s in (1500.0, 3000.0)])
    phi = math.radians(25.0)
    assert sticky.cohesion == pytest.approx(200.0)
    assert sticky.unconfined_yield_strength == pytest.approx(400.0 * math.cos(phi) / (1.0 - math.sin(phi)))
    with pytest.raises(ValueError):
        fit_yield_locus([_result(3000.0, 1000.0)])


# ---------------------------------------------------------------- solver failures
def test_missing_binary_names_the_run_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NEURALDEM_LIGGGHTS", "/nonexistent")
    with pytest.raises(SolverError, match=str(tmp_path / "run")):
        run_shear_test(Material(), ShearSettings.tiny(), tmp_path / "run")


@pytest.mark.solver
def test_solver_error_names_the_run_folder(tmp_path: Path) -> None:
    # a 5 ms timestep lets every particle fall through the floor: LIGGGHTS stops with an ERROR line
    with pytest.raises(SolverError, match=rf"{tmp_path / 'run'}.*ERROR"):
        run_shear_test(Material(dt=5e-3), ShearSettings.tiny(), tmp_path / "run")


@pytest.mark.solver
def test_timeout_names_the_run_folder(tmp_path: Path) -> None:
    with pytest.raises(SolverError, match=rf"{tmp_path / 'run'}.*time limit"):
        run_shear_test(Material(), ShearSettings.tiny(), tmp_path / "run", timeout_s=0.3)


# ---------------------------------------------------------------- physics (tiny preset)
@pytest.mark.solver
def test_theta_rises_with_rolling_friction(tmp_path: Path) -> None:
    """mu_s 0.5: theta ~20-21 deg at mu_r 0 and ~29-32 deg at mu_r 0.5 on the tiny preset (3 packings,
    measured); the small preset gives 20.8 / 29.6. Required margin: 4 deg."""
    settings = ShearSettings.tiny()
    r0 = run_shear_test(Material(mu_s=0.5, mu_r=0.0), settings, tmp_path / "mur0")
    r5 = run_shear_test(Material(mu_s=0.5, mu_r=0.5), settings, tmp_path / "mur05")
    for r in (r0, r5):
        assert 10.0 < r.theta_deg < 40.0
        assert abs(r.theta_top_deg - r.theta_bottom_deg) < 1.5  # both slabs feel the same stress ratio
        assert r.normal_stress_measured == pytest.approx(settings.normal_stress, rel=0.03)
        assert r.n_particles + r.n_lost == settings.n_particles and r.n_lost <= 5
        assert 0.45 < r.solid_fraction < 0.7
        assert r.cpu_s > 0 and math.isfinite(r.theta_err_deg)
        assert r.mohr_coulomb_deg >= r.theta_deg - 1.0
    assert r5.theta_deg > r0.theta_deg + 4.0, (r0.theta_deg, r5.theta_deg)
    assert (tmp_path / "mur0" / "in.shear").exists() and (tmp_path / "mur0" / "log.liggghts").exists()
