"""DPMFoam fluidized bed: scene checks, start packing, and real runs (fluid continuity per step, particles
kept, resume from a truncated time directory, a diverging and a crashing case recorded, OpenFOAM missing)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from neuraldem.errors import ConfigError, DataError, SolverError
from neuraldem.scenes.fluidized_bed.solver import (
    FluidizedBedScene,
    finish,
    latest_complete_time,
    random_packing,
    read_flux_monitor,
    read_trajectory,
    run_fluidized_bed,
)
from neuraldem.sim import openfoam
from neuraldem.sim.foam_reader import FoamCase
from tests.helpers import REPO


@pytest.fixture(scope="module")
def tiny_scene() -> FluidizedBedScene:
    cfg = OmegaConf.merge(OmegaConf.load(REPO / "conf/data/fb_small.yaml").scene,
                          OmegaConf.load(REPO / "conf/data/fb_tiny.yaml").scene)
    return FluidizedBedScene.from_config(cfg, "data.scene")


def test_scene_defaults_match_the_canonical_config():
    scene = FluidizedBedScene.from_config(OmegaConf.load(REPO / "conf/data/fb_small.yaml").scene, "data.scene")
    assert scene == FluidizedBedScene()
    assert scene.minimum_fluidization_velocity == pytest.approx(1.07, abs=0.01)
    assert scene.grid.shape == (12, 1, 30) and scene.grid.cell_volume == pytest.approx(0.004 * 0.006 * 0.004)


@pytest.mark.parametrize("override,message", [
    ({"cells": [12, 1]}, "data.scene.cells"),
    ({"drag": "Stokes"}, "data.scene.drag='Stokes' is invalid"),
    ({"snapshot_interval": 0.00015}, "multiple of data.scene.dt"),
    ({"spinup_time": 0.015}, "spinup_time=0.015 is invalid"),
    ({"n_particles": 20000}, "start packing"),
    ({"front_back": "periodic"}, "data.scene.front_back"),
    ({"colour": "red"}, "unknown key"),
])
def test_bad_scene_values_name_the_key(override: dict, message: str):
    with pytest.raises(ConfigError, match=message):
        FluidizedBedScene.from_config(override, "data.scene")


def test_random_packing_has_no_overlaps_and_differs_by_seed(tiny_scene):
    scene = tiny_scene
    a = random_packing(scene, np.random.default_rng(1))
    b = random_packing(scene, np.random.default_rng(2))
    assert a.shape == (300, 3) and not np.allclose(a, b)
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(a).query(a, k=2)
    assert dist[:, 1].min() >= scene.diameter
    r = scene.diameter / 2
    assert np.all(a >= r) and np.all(a <= np.array([scene.width, scene.thickness, scene.height]) - r)


def test_openfoam_missing_or_unset_gives_the_fix(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, tiny_scene):
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(SolverError, match="not found on PATH.*apt-get install openfoam"):
        run_fluidized_bed(tiny_scene, 1.5, 0.01, tmp_path / "case", seed=0)
    monkeypatch.setenv("WM_PROJECT_DIR", str(tmp_path / "nowhere"))
    with pytest.raises(SolverError, match="set WM_PROJECT_DIR"):
        openfoam.foam_env()


@pytest.mark.solver
def test_fluid_inflow_equals_outflow_every_step(fb_tiny_case: Path):
    """Continuity of the air: volume flow in through the bottom = out through the top in every solver step
    (pressure solver tolerance 1e-7), and equal to the superficial inlet velocity times the inlet area."""
    import json

    u0 = json.loads((fb_tiny_case / "neuraldem_case.json").read_text())["inlet_velocity"]
    t_in, f_in = read_flux_monitor(fb_tiny_case, "flux_bottom")
    t_out, f_out = read_flux_monitor(fb_tiny_case, "flux_top")
    assert len(t_in) == len(t_out) == 2500 and np.array_equal(t_in, t_out)
    steps = t_in > 0.0001 + 1e-9  # the first step starts the flow from rest
    inflow, outflow = -f_in[steps], f_out[steps]
    area = 0.024 * 0.006
    np.testing.assert_allclose(inflow, u0 * area, rtol=1e-6)
    imbalance = np.abs(inflow - outflow) / inflow
    assert imbalance.max() < 1e-5, imbalance.max()


@pytest.mark.solver
def test_run_keeps_every_particle_and_the_solver_alpha_volume(fb_tiny_case: Path, tiny_scene):
    case = FoamCase(fb_tiny_case)
    traj = read_trajectory(case, tiny_scene.grid, tiny_scene.spinup_time, tiny_scene.snapshot_interval)
    assert traj.positions.shape == (21, 300, 3) and traj.times[-1] == pytest.approx(0.2)
    assert np.isfinite(traj.positions).all() and not np.isfinite(traj.lost_time).any()
    solid = (1 - traj.fluid_fraction).sum(axis=(1, 2, 3)) * tiny_scene.grid.cell_volume
    np.testing.assert_allclose(solid, 300 * tiny_scene.particle_volume, rtol=1e-6)
    # the bed is fluidized: particles move between snapshots, air rises
    assert np.median(np.linalg.norm(np.diff(traj.positions, axis=0), axis=2)) > 1e-4
    assert traj.fluid_velocity[..., 2].mean() > 1.0


@pytest.mark.solver
def test_truncated_time_directory_is_read_as_error_and_resumed(fb_tiny_case: Path, tiny_scene,
                                                               tmp_path: Path):
    case_dir = tmp_path / "case"
    shutil.copytree(fb_tiny_case, case_dir)
    for name in ("0.23", "0.24", "0.25"):  # as if killed while writing 0.23
        shutil.rmtree(case_dir / name)
    pos = case_dir / "0.22" / "lagrangian" / "kinematicCloud" / "positions"
    pos.write_text(pos.read_text()[:3000])
    with pytest.raises(DataError, match=str(pos)):
        read_trajectory(FoamCase(case_dir), tiny_scene.grid, 0.05, 0.01)
    # a restart deletes the damaged directory and resumes DPMFoam from 0.21
    assert latest_complete_time(FoamCase(case_dir)) == "0.21"
    assert not (case_dir / "0.22").exists()
    import json

    stamp = json.loads((case_dir / "neuraldem_case.json").read_text())
    shutil.copytree(case_dir, tmp_path / "again")
    (tmp_path / "again" / "0.21" / "U.air").write_text("garbage")  # and a second damaged file
    res = run_fluidized_bed(tiny_scene, stamp["inlet_velocity"], stamp["duration"], tmp_path / "again",
                            stamp["seed"])
    assert res.status == "ok", res.reason
    assert res.diagnostics["resumed_from"] == "0.2"
    assert res.trajectory is not None and len(res.trajectory.times) == 21
    assert res.cost["attempts"] == 2  # the original run and the resumed one, CPU of both counted


@pytest.mark.solver
def test_diverging_case_is_failed_with_reason(tmp_path: Path):
    scene = FluidizedBedScene(width=0.024, height=0.06, cells=(6, 1, 15), n_particles=300, spinup_time=0.01)
    res = run_fluidized_bed(scene, 60.0, 0.02, tmp_path / "case", seed=1)  # 56 x Umf: the flow blows up
    assert res.status == "failed" and res.reason.startswith("diverged: fluid speed")


@pytest.mark.solver
def test_crashing_case_is_failed_with_the_solver_message(tmp_path: Path, tiny_scene):
    case = tmp_path / "case"
    res = run_fluidized_bed(tiny_scene, 1.5, 0.01, case, seed=3)
    assert res.status == "ok"
    props = case / "constant" / "kinematicCloudProperties"
    props.write_text(props.read_text().replace("ErgunWenYuDrag", "NoSuchDrag"))
    for name in ("0.05", "0.06"):
        shutil.rmtree(case / name)
    res = run_fluidized_bed(tiny_scene, 1.5, 0.01, case, seed=3)  # resumes from 0.04 with the broken dict
    assert res.status == "failed"
    assert "FOAM FATAL" in res.reason and "NoSuchDrag" in res.reason and "log.DPMFoam" in res.reason


@pytest.mark.solver
def test_lost_particles_are_counted_not_dropped(fb_tiny_case: Path, tiny_scene, tmp_path: Path):
    case_dir = tmp_path / "case"
    shutil.copytree(fb_tiny_case, case_dir)
    # from t = 0.1 s (solver time 0.15) on, two particles are gone, as through a patch that lets them escape
    for t in range(15, 26):
        _remove_particles(case_dir / f"{t / 100:g}", keep=lambda ids: ids < 298)
    res = finish(tiny_scene, FoamCase(case_dir), 0.2, {}, {})
    assert res.status == "failed" and "2 particle(s) left the domain (first at t = 0.1 s" in res.reason
    assert res.diagnostics["n_lost"] == 2
    traj = res.trajectory
    assert traj is not None and traj.n_particles == 300
    gone = traj.orig_id >= 298
    assert np.isnan(traj.positions[10:, gone]).all() and np.isfinite(traj.positions[:10]).all()
    np.testing.assert_allclose(traj.lost_time[gone], 0.1)
    loose = FluidizedBedScene(**{**tiny_scene.as_dict(), "cells": tiny_scene.cells, "max_lost_particles": 2})
    assert finish(loose, FoamCase(case_dir), 0.2, {}, {}).status == "ok"


def _remove_particles(time_dir: Path, keep) -> None:
    """Rewrite a time directory's cloud without the particles whose origId fails `keep`."""
    from neuraldem.sim.foam_reader import read_cloud_field

    d = time_dir / "lagrangian" / "kinematicCloud"
    mask = keep(read_cloud_field(d / "origId"))
    n = int(mask.sum())

    def rows(values: np.ndarray, fmt) -> str:
        return f"{n}\n(\n" + "".join(fmt(v) + "\n" for v in values[mask]) + ")\n"

    def vec(v: np.ndarray) -> str:
        return "(" + " ".join(repr(float(x)) for x in v) + ")"

    openfoam.write_foam_file(d / "positions", "Cloud<basicKinematicCollidingParcel>", "positions",
                             rows(read_cloud_field(d / "positions"), lambda v: vec(v) + " 0"))
    for name, cls, fmt in (("origId", "labelField", lambda v: str(int(v))),
                           ("origProcId", "labelField", lambda v: str(int(v))),
                           ("d", "scalarField", lambda v: repr(float(v))), ("U", "vectorField", vec)):
        values = read_cloud_field(d / name)
        openfoam.write_foam_file(d / name, cls, name, rows(values,
                                                           lambda v, f=fmt: f(v)))
    (time_dir / "uniform" / "lagrangian" / "kinematicCloud" / "cloudProperties").unlink()
