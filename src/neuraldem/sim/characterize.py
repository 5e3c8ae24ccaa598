"""Macroscopic characterization of a material: internal friction angle theta and angle of repose.

`characterize` runs the shear test (`neuraldem.sim.shear`) and the heap test (`neuraldem.sim.heap`) for one
material and returns a flat dict whose `theta` and `repose` (degrees) condition the hopper surrogate in
place of the microscopic mu_s / mu_r. The result is cached in `workdir/characterization.json` together with
every input (material, both settings); a rerun with identical inputs returns the cached dict without
starting the solver, any change of an input reruns both tests.

The flow function coefficient ffc of the paper is not computed: the simulated material is cohesionless, its
yield locus passes through the origin, so the unconfined yield strength is ~0 and ffc is infinite / noise
(see docs/characterization.md). The angle of repose is the second macroscopic scalar instead.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from neuraldem.errors import SolverError
from neuraldem.sim.heap import HeapSettings, run_heap_test
from neuraldem.sim.material import Material
from neuraldem.sim.shear import ShearSettings, run_shear_test

CACHE_NAME = "characterization.json"
# bump when the meaning of a result changes (input files, analysis), so that old caches are recomputed
CACHE_VERSION = 1


def characterization_inputs(material: Material, shear_settings: ShearSettings,
                            heap_settings: HeapSettings) -> dict[str, Any]:
    """Everything the result depends on, as plain JSON values (the cache key)."""
    inputs = {"version": CACHE_VERSION, "material": material.as_dict(), "shear": shear_settings.as_dict(),
              "heap": heap_settings.as_dict()}
    return json.loads(json.dumps(inputs))  # tuples -> lists, as they come back from the file


def _plain(value: Any) -> Any:
    """JSON-safe and round-trip stable: NaN / inf -> None, numpy scalars -> Python numbers."""
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "item"):
        return _plain(value.item())
    return value


def cached_characterization(material: Material, shear_settings: ShearSettings, heap_settings: HeapSettings,
                            workdir: Path | str) -> dict[str, Any] | None:
    """The cached result in `workdir` if it was computed from exactly these inputs, else None."""
    path = Path(workdir) / CACHE_NAME
    try:
        stored = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(stored, dict) or stored.get("inputs") != characterization_inputs(
            material, shear_settings, heap_settings):
        return None
    result = stored.get("result")
    return result if isinstance(result, dict) else None


def _write_atomic(path: Path, payload: dict[str, Any]) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(payload, indent=1, allow_nan=False) + "\n")
    os.replace(tmp, path)


def characterize(material: Material, shear_settings: ShearSettings | None, heap_settings: HeapSettings | None,
                 workdir: Path | str, timeout_s: float | None = None) -> dict[str, Any]:
    """theta (shear test) and repose (heap test) of `material`, cached in `workdir/characterization.json`.

    `None` settings mean the default ("small") preset; `timeout_s` limits each solver run. The tests run
    in `workdir/shear` and `workdir/heap`. Returns a flat dict:

        theta, theta_err, theta_mohr_coulomb, solid_fraction   (shear test; degrees, -)
        repose, heap_formed, heap_height, repose_fit_r2         (heap test; degrees, -, d, -)
        shear_cpu_s, heap_cpu_s, cpu_s, wall_s                  (cost)
        shear, heap                                             (all diagnostics of each test)

    Raises ConfigError for invalid settings (before any run) and SolverError naming the failed test and
    its run folder."""
    shear_settings = shear_settings if shear_settings is not None else ShearSettings()
    heap_settings = heap_settings if heap_settings is not None else HeapSettings()
    shear_settings.validate("shear")
    heap_settings.validate("heap")
    workdir = Path(workdir)
    cached = cached_characterization(material, shear_settings, heap_settings, workdir)
    if cached is not None:
        return cached
    workdir.mkdir(parents=True, exist_ok=True)
    label = f"material mu_s={material.mu_s:g}, mu_r={material.mu_r:g}"
    try:
        shear = run_shear_test(material, shear_settings, workdir / "shear", timeout_s=timeout_s)
    except SolverError as err:
        raise SolverError(f"characterization of {label}: the shear test failed: {err}") from err
    try:
        heap = run_heap_test(material, heap_settings, workdir / "heap", timeout_s=timeout_s)
    except SolverError as err:
        raise SolverError(f"characterization of {label}: the heap test failed: {err}") from err
    result = _plain({
        "theta": shear.theta_deg,
        "theta_err": shear.theta_err_deg,
        "theta_mohr_coulomb": shear.mohr_coulomb_deg,
        "solid_fraction": shear.solid_fraction,
        "repose": heap.repose_deg,
        "heap_formed": heap.heap_formed,
        "heap_height": heap.heap_height,
        "repose_fit_r2": heap.fit_r2,
        "shear_cpu_s": shear.cpu_s,
        "heap_cpu_s": heap.cpu_s,
        "cpu_s": shear.cpu_s + heap.cpu_s,
        "wall_s": shear.wall_s + heap.wall_s,
        "shear": shear.as_dict(),
        "heap": heap.as_dict(),
    })
    _write_atomic(workdir / CACHE_NAME, {"inputs": characterization_inputs(material, shear_settings,
                                                                           heap_settings),
                                         "result": result})
    return result
