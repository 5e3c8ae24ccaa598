"""The doctor: every check reports one line; hiding a required part turns its line red with a fix."""

from __future__ import annotations

from pathlib import Path

import pytest

from neuraldem import doctor
from tests.helpers import run_module


def test_torch_cluster_check_knows_the_answer():
    check = doctor.check_torch_cluster()
    assert check.ok, check.line()
    assert "radius query correct" in check.detail


@pytest.mark.solver
def test_all_green_here():
    proc = run_module("neuraldem", "doctor")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert sum(line.startswith("[") for line in lines) == len(doctor.CHECKS)
    assert "all required checks passed" in lines[-1]


def test_missing_liggghts_is_red_with_the_fix():
    proc = run_module("neuraldem", "doctor", "only=[liggghts]", env={"NEURALDEM_LIGGGHTS": "no-such-liggghts"})
    assert proc.returncode == 1
    line = proc.stdout.splitlines()[0]
    assert line.startswith("[FAIL] LIGGGHTS") and "apt-get install liggghts" in line
    assert "Traceback" not in proc.stdout + proc.stderr
    assert "old spelling" not in proc.stderr


def test_unset_openfoam_environment_is_red_with_the_fix():
    proc = run_module("neuraldem", "doctor", "only=[openfoam]", env={"WM_PROJECT_DIR": "/nonexistent/openfoam"})
    assert proc.returncode == 1
    line = proc.stdout.splitlines()[0]
    assert line.startswith("[FAIL] OpenFOAM") and "WM_PROJECT_DIR" in line and "fix:" in line


def test_unwritable_data_dir_is_red(tmp_path: Path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    proc = run_module("neuraldem", "doctor", "only=[data-dir]", env={"NEURALDEM_DATA": str(blocker / "sub")})
    assert proc.returncode == 1
    assert proc.stdout.startswith("[FAIL] data dir") and "NEURALDEM_DATA" in proc.stdout


def test_gpu_absence_only_warns():
    check = doctor.check_gpu()
    assert not check.required
    assert check.line().startswith("[  ok]" if check.ok else "[warn]")
