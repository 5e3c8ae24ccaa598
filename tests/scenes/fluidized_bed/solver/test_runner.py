"""DPMFoam fluidized-bed runs: OpenFOAM missing, resume from a truncated time directory, a diverging and a
crashing case recorded, lost particles counted."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from neuraldem.errors import DataError, SolverError
from neuraldem.scenes.fluidized_bed.solver.reader import latest_complete_time, read_trajectory
from neuraldem.scenes.fluidized_bed.solver.runner import finish, run_fluidized_bed
from neuraldem.scenes.fluidized_bed.solver.scene import BedScene
from neuraldem.sim import openfoam
from neuraldem.sim.foam_reader import FoamCase


def test_openfoam_missing_or_unset_gives_the_fix(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, tiny_scene):
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(SolverError, match="not found on PATH.*apt-get install openfoam"):
        run_fluidized_bed(tiny_scene, 1.5, 0.01, tmp_path / "case", seed=0)
    monkeypatch.setenv("WM_PROJECT_DIR", str(tmp_path / "nowhere"))
    with pytest.raises(SolverError, match="set WM_PROJECT_DIR"):
        openfoam.foam_env()


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
    scene = BedScene(width=0.024, height=0.06, cells=(6, 1, 15), n_particles=300, spinup_time=0.01)
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
    loose = BedScene(**{**tiny_scene.as_dict(), "cells": tiny_scene.cells, "max_lost_particles": 2})
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
