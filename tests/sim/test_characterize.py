"""characterize(): theta + repose of a material, cached in characterization.json."""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace
from pathlib import Path

import pytest

import neuraldem.sim.characterize as ch
from neuraldem.errors import ConfigError, SolverError
from neuraldem.sim.heap import HeapSettings
from neuraldem.sim.material import Material
from neuraldem.sim.shear import ShearSettings


def _no_solver(*args: object, **kwargs: object) -> None:
    raise AssertionError("the solver must not run for a cached characterization")


@pytest.mark.solver
def test_characterize_is_cached_and_reruns_on_changes(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    material = Material(mu_s=0.5, mu_r=0.1)
    shear, heap = ShearSettings.tiny(), HeapSettings.tiny()
    first = ch.characterize(material, shear, heap, tmp_path, timeout_s=120)

    assert 10.0 < first["theta"] < 40.0 and math.isfinite(first["theta_err"])
    assert 0.0 <= first["repose"] < 45.0
    assert first["shear_cpu_s"] > 0 and first["heap_cpu_s"] > 0
    assert first["cpu_s"] == pytest.approx(first["shear_cpu_s"] + first["heap_cpu_s"])
    assert first["shear"]["theta_deg"] == first["theta"] and first["heap"]["repose_deg"] == first["repose"]
    stored = json.loads((tmp_path / ch.CACHE_NAME).read_text())
    assert stored["result"] == first
    assert stored["inputs"]["material"]["mu_r"] == 0.1
    assert not list(tmp_path.glob(".*.tmp"))  # the temp file was renamed into place
    logs = {p: p.stat().st_mtime_ns for p in tmp_path.glob("*/log.liggghts")}
    assert len(logs) == 2

    # same inputs: the cached dict, without starting the solver
    monkeypatch.setattr(ch, "run_shear_test", _no_solver)
    monkeypatch.setattr(ch, "run_heap_test", _no_solver)
    t0 = time.perf_counter()
    again = ch.characterize(material, shear, heap, tmp_path, timeout_s=120)
    assert again == first
    assert time.perf_counter() - t0 < 0.5
    assert {p: p.stat().st_mtime_ns for p in tmp_path.glob("*/log.liggghts")} == logs

    # a changed material or setting reruns both tests (spied here, the real runs are covered above)
    calls: list[str] = []
    real_shear, real_heap = first["shear"], first["heap"]

    class _Fake:
        def __init__(self, values: dict) -> None:
            self.__dict__.update(values)

        def as_dict(self) -> dict:
            return dict(self.__dict__)

    def fake_shear(m: Material, s: ShearSettings, workdir: Path, timeout_s: float | None = None) -> _Fake:
        calls.append(f"shear {m.mu_s} {m.mu_r} {s.normal_stress}")
        return _Fake({**real_shear, "theta_deg": 33.0})

    def fake_heap(m: Material, s: HeapSettings, workdir: Path, timeout_s: float | None = None) -> _Fake:
        calls.append(f"heap {m.mu_s} {m.mu_r}")
        return _Fake({**real_heap, "repose_deg": 30.0})

    monkeypatch.setattr(ch, "run_shear_test", fake_shear)
    monkeypatch.setattr(ch, "run_heap_test", fake_heap)
    changed = ch.characterize(replace(material, mu_r=0.3), shear, heap, tmp_path, timeout_s=120)
    assert calls == ["shear 0.5 0.3 3000.0", "heap 0.5 0.3"]
    assert changed["theta"] == 33.0 and changed["repose"] == 30.0
    assert json.loads((tmp_path / ch.CACHE_NAME).read_text())["inputs"]["material"]["mu_r"] == 0.3
    calls.clear()
    ch.characterize(replace(material, mu_r=0.3), replace(shear, normal_stress=1500.0), heap, tmp_path)
    assert calls == ["shear 0.5 0.3 1500.0", "heap 0.5 0.3"]


def test_corrupt_cache_is_ignored(tmp_path: Path) -> None:
    (tmp_path / ch.CACHE_NAME).write_text("{not json")
    assert ch.cached_characterization(Material(), ShearSettings.tiny(), HeapSettings.tiny(), tmp_path) is None


def test_bad_settings_fail_before_any_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ch, "run_shear_test", _no_solver)
    with pytest.raises(ConfigError, match=r"shear\.normal_stress"):
        ch.characterize(Material(), replace(ShearSettings.tiny(), normal_stress=-5.0), HeapSettings.tiny(),
                        tmp_path)
    with pytest.raises(ConfigError, match=r"heap\.lift_speed"):
        ch.characterize(Material(), ShearSettings.tiny(), replace(HeapSettings.tiny(), lift_speed=0.0),
                        tmp_path)


def test_missing_solver_is_a_clear_solver_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NEURALDEM_LIGGGHTS", "/nonexistent")
    with pytest.raises(SolverError, match=rf"shear test failed.*{tmp_path / 'shear'}.*not found"):
        ch.characterize(Material(), ShearSettings.tiny(), HeapSettings.tiny(), tmp_path)
    assert not (tmp_path / ch.CACHE_NAME).exists()


@pytest.mark.solver
def test_failed_heap_run_is_a_solver_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The heap run is killed at the time limit: the message names the heap test and its folder."""
    monkeypatch.setattr(ch, "run_shear_test", lambda *a, **k: None)  # skip the shear test
    with pytest.raises(SolverError, match=rf"heap test failed.*{tmp_path / 'heap'}.*time limit"):
        ch.characterize(Material(), ShearSettings.tiny(), HeapSettings.tiny(), tmp_path, timeout_s=0.3)
    assert not (tmp_path / ch.CACHE_NAME).exists()


@pytest.mark.slow
@pytest.mark.solver
def test_small_preset_centre_point_and_cohesionless_yield_locus(tmp_path: Path) -> None:
    """Production preset at mu_s 0.5 / mu_r 0.1 (~2.5 CPU-min): theta 24.0, repose 15.0 deg measured;
    shear tests at 1.5 / 3 / 6 kPa give a yield locus through the origin (c = 28 Pa, 2 % of tau)."""
    from neuraldem.sim.shear import ShearResult, fit_yield_locus, run_shear_test

    material = Material(mu_s=0.5, mu_r=0.1)
    result = ch.characterize(material, ShearSettings(), HeapSettings(), tmp_path / "char")
    assert 22.0 < result["theta"] < 26.0 and result["theta_err"] < 1.0
    assert 11.0 < result["repose"] < 20.0 and result["heap_formed"]
    runs = [run_shear_test(material, replace(ShearSettings(), normal_stress=sig), tmp_path / f"sig{sig:g}")
            for sig in (1500.0, 6000.0)]
    at_3kpa = ShearResult(**result["shear"])
    locus = fit_yield_locus([*runs, at_3kpa])
    assert abs(locus.cohesion) < 0.08 * at_3kpa.shear_stress  # zero within the packing scatter
    assert abs(locus.angle_deg - result["theta"]) < 1.5
