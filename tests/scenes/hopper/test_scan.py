"""`neuraldem scan`: a design chart over two parameters from the shipped GP, LIGGGHTS checks marked on it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from neuraldem.errors import ConfigError
from neuraldem.scenes.hopper.parameters import PARAMETERS
from neuraldem.scenes.hopper.scan import parse_axes, pick_points
from tests.helpers import run_module

NAMES = ["alpha", "mu_s", "mu_r"]


def items(args: list[str]) -> dict[str, str]:
    return dict(a.split("=") for a in args)


def test_a_small_scan_writes_maps_the_boundary_and_json(tmp_path: Path):
    proc = run_module("neuraldem", "scan", "hopper", "alpha=0:60:7", "mu_s=0.1:0.9:4", "mu_r=0.1",
                      f"out={tmp_path}")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    scan = json.loads((tmp_path / "scan.json").read_text())
    assert scan["n_points"] == 28 and len(scan["grids"]["drainage_t95.mean"]) == 7
    index = np.array(scan["grids"]["mass_flow_index.mean"])
    assert index.shape == (7, 4) and np.all(np.array(scan["grids"]["mass_flow_index.low"]) <= index + 1e-12)
    assert (tmp_path / "design_chart.png").stat().st_size > 10_000


def test_parse_axes_two_ranges_and_fixed_values():
    axes, fixed = parse_axes(items(["alpha=0:60:31", "mu_s=0.05:1:20", "mu_r=0.1"]), NAMES, "hopper", PARAMETERS)
    assert list(axes) == ["alpha", "mu_s"] and len(axes["alpha"]) == 31 and axes["mu_s"][-1] == 1.0
    assert fixed == {"mu_r": 0.1}


@pytest.mark.parametrize(("items", "expected"), [
    (["alpha=0:60:31", "mu_s=0.3", "mu_r=0.1"], "exactly two ranges"),
    (["alpha=0:60:1", "mu_s=0.05:1:20", "mu_r=0.1"], "N >= 2"),
    (["alpha=60:0:5", "mu_s=0.05:1:20", "mu_r=0.1"], "HI > LO"),
    (["alpha=0:60:31", "mu_s=0.05:1:20"], "missing hopper parameter(s) mu_r"),
    (["alpha=0:80:31", "mu_s=0.05:1:20", "mu_r=0.1"], "outside what the solver can run"),
    (["alpha=0:60:31", "mu_s=0.05:1:20", "phi=3"], "unknown hopper parameter 'phi'"),
    (["alpha=0:60:1000", "mu_s=0.05:1:1000", "mu_r=0.1"], "more than"),
])
def test_bad_scans_are_refused(items: list[str], expected: str):
    with pytest.raises(ConfigError, match=None) as err:
        parse_axes(dict(i.split("=") for i in items), NAMES, "hopper", PARAMETERS)
    assert expected in str(err.value)


def test_checked_points_are_spread_over_the_first_axis():
    picked = pick_points((31, 20), 4, seed=0)
    edges = [0, 7, 15, 23, 31]  # four strata of the 31 values of the first axis
    assert len(picked) == 4 and all(edges[i] <= a < edges[i + 1] and 0 <= b < 20 for i, (a, b) in enumerate(picked))
    assert pick_points((31, 20), 4, seed=0) == picked != pick_points((31, 20), 4, seed=1)


@pytest.mark.solver
def test_verify_marks_liggghts_points_and_reuses_them(tiny_pretrained: Path, tmp_path: Path):
    env = {"NEURALDEM_PRETRAINED_DIR": str(tiny_pretrained)}
    args = ("scan", "hopper", "alpha=20:50:3", "mu_s=0.2:0.6:2", "mu_r=0.1", "model=hopper_tiny_test", "verify=1",
            f"out={tmp_path}")
    proc = run_module("neuraldem", *args, env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    scan = json.loads((tmp_path / "scan.json").read_text())
    assert len(scan["liggghts"]) == 1 and scan["liggghts"][0]["status"] == "ok"
    assert "| t95 GP [95 %] [s] | t95 LIGGGHTS [s] |" in (tmp_path / "scan.md").read_text()
    again = run_module("neuraldem", *args, env=env)  # the finished solver run is read back, not rerun
    assert again.returncode == 0 and "LIGGGHTS 1/1" not in again.stderr


def test_a_scan_of_the_one_parameter_bed_is_refused_naming_the_scenes_that_have_one(capsys):
    from neuraldem.scan import main

    with pytest.raises(SystemExit) as done:
        main(["fb", "inlet_velocity=1.2:2.2:11"])
    err = capsys.readouterr().err
    assert done.value.code == 2 and "neuraldem scan has no answers for the fluidized_bed scene" in err
    assert "choose one of: hopper" in err
