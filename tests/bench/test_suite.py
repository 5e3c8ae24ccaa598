"""`all` runs the hopper benchmarks and, with fb_ckpt=, the fluidized bed's, with consistent options (each
benchmark's command line in key=value form); `render` redraws from results files."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from neuraldem.bench import suite
from neuraldem.bench.__main__ import main as bench_main
from neuraldem.bench.report import default_path, write_results
from neuraldem.bench.suite import plan
from neuraldem.errors import ConfigError
from neuraldem.scenes.hopper.bench import scaling as hopper_scaling
from tests.scenes.hopper.bench.test_scaling import HAND_MADE


def opts(argv: list[str]) -> dict[str, str]:
    """A benchmark command line (key=value tokens) as a dict; every token is key=value and every key is once."""
    pairs = [token.split("=", 1) for token in argv]
    assert all(len(p) == 2 for p in pairs) and len({k for k, _ in pairs}) == len(pairs), argv
    return dict(pairs)


def test_plan_measures_everything_by_default(tmp_path: Path):
    steps = dict(plan([Path("/runs")], Path("/c.ckpt"), None, tmp_path, no_solver=False, repeats=5, threads=1))
    assert list(steps) == ["hopper_speed", "hopper_scaling", "speed_accuracy", "right_sizing", "hopper_stability"]
    assert "reuse_dataset" not in opts(steps["hopper_speed"]) and "skip_solver" not in opts(steps["speed_accuracy"])
    assert opts(steps["right_sizing"])["from_file"] == str(tmp_path / "speed_accuracy.json")
    assert opts(steps["hopper_speed"])["repeats"] == "5"


def test_plan_without_out_dir_writes_each_file_into_the_folder_of_its_question():
    steps = dict(plan([Path("/runs")], Path("/c.ckpt"), None, None, no_solver=False, repeats=1, threads=1,
                      fb_ckpts=[Path("/fb.ckpt")]))
    for name in ("hopper_speed", "hopper_scaling", "speed_accuracy", "right_sizing", "hopper_stability", "fb_speed",
                 "fb_stability"):
        assert opts(steps[name])["out"] == str(default_path(name))
    assert opts(steps["right_sizing"])["from_file"] == str(default_path("speed_accuracy"))
    assert "hopper/speed" in opts(steps["hopper_speed"])["out"]
    assert "fluidized_bed/stability" in opts(steps["fb_stability"])["out"]


def test_plan_without_solver_reuses_what_exists(tmp_path: Path):
    (tmp_path / "hopper_scaling.json").write_text("{}")
    steps = dict(plan([Path("/runs")], Path("/c.ckpt"), Path("/d"), tmp_path, no_solver=True, repeats=3, threads=2,
                      skip_unevaluated=True))
    assert opts(steps["hopper_speed"])["reuse_dataset"] == "true"
    assert opts(steps["hopper_scaling"])["reuse_solver"] == str(tmp_path / "hopper_scaling.json")
    accuracy = opts(steps["speed_accuracy"])
    assert accuracy["skip_solver"] == "true" and "reuse_solver" not in accuracy  # nothing earlier to reuse
    assert accuracy["skip_unevaluated"] == "true" and accuracy["dataset"] == "/d"


def test_all_without_solver_then_render(evaluated_runs: Path, tiny_checkpoint: Path, hopper_tiny_dataset: Path,
                                        tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    # `all` uses the scaling sweep's defaults, sized for the real measurement: shrink them for the test
    monkeypatch.setattr(hopper_scaling, "DEFAULT_QUERIES", (50,))
    monkeypatch.setattr(hopper_scaling, "DEFAULT_TOKENS", (4,))
    argv = ["all", f"runs=[{evaluated_runs / 'tiny'}]", f"ckpt={tiny_checkpoint}", f"dataset={hopper_tiny_dataset}",
            "no_solver=true", "repeats=1", f"out_dir={tmp_path}"]
    assert bench_main(argv) == 0
    names = {"hopper_speed.json", "hopper_speed.md", "hopper_scaling.json", "hopper_scaling.png",
             "speed_accuracy.json", "speed_accuracy.png", "speed_accuracy.md", "right_sizing.json", "right_sizing.md",
             "hopper_stability.json", "hopper_stability.png", "hopper_stability.md"}
    assert names <= {p.name for p in tmp_path.iterdir()}
    for name in ("hopper_scaling.png", "speed_accuracy.png", "right_sizing.md", "hopper_stability.png"):
        (tmp_path / name).unlink()
    assert bench_main(["render", f"out_dir={tmp_path}"]) == 0
    assert (tmp_path / "hopper_scaling.png").is_file() and (tmp_path / "right_sizing.md").is_file()
    assert (tmp_path / "hopper_stability.png").is_file()


def test_render_from_a_results_file(tmp_path: Path):
    write_results("hopper_scaling", HAND_MADE, command="test", path=tmp_path / "hopper_scaling.json", machine={})
    assert bench_main(["render", f"out_dir={tmp_path}"]) == 0
    assert (tmp_path / "hopper_scaling.png").is_file()


def test_render_with_nothing_to_render(tmp_path: Path, capsys: pytest.CaptureFixture):
    assert bench_main(["render", f"out_dir={tmp_path}"]) == 2
    err = capsys.readouterr().err
    assert "no benchmark results in" in err and "run `neuraldem bench all ...` first" in err


def test_plan_with_fluidized_bed_checkpoints(tmp_path: Path):
    fb = [Path("/fb/a.ckpt"), Path("/fb/b.ckpt")]
    steps = dict(plan([Path("/runs")], Path("/c.ckpt"), None, tmp_path, no_solver=False, repeats=4, threads=1,
                      fb_ckpts=fb, fb_dataset=Path("/fbd"), fb_labels=["model", "no noise"]))
    assert list(steps)[-2:] == ["fb_speed", "fb_stability"] and "hopper_speed" in steps
    speed, stability = opts(steps["fb_speed"]), opts(steps["fb_stability"])
    assert speed["ckpt"] == "/fb/a.ckpt" and "reuse_dataset" not in speed  # the first is timed
    assert speed["repeats"] == "4" and "threads" not in speed  # 1 and all threads itself
    assert stability["ckpt"] == "[/fb/a.ckpt,/fb/b.ckpt]"  # all go into the map
    assert stability["labels"] == "[model,no noise]"
    assert speed["dataset"] == "/fbd" and stability["dataset"] == "/fbd"
    assert stability["out"] == str(tmp_path / "fb_stability.json")
    only_fb = dict(plan(None, None, None, tmp_path, no_solver=True, repeats=3, threads=1, fb_ckpts=fb[:1]))
    assert list(only_fb) == ["fb_speed", "fb_stability"] and opts(only_fb["fb_speed"])["reuse_dataset"] == "true"


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"runs": [Path("/runs")], "ckpt": None}, "runs= and ckpt= go together"),
    ({"runs": None, "ckpt": None}, "nothing to run: give runs=DIR ckpt=CKPT"),
    ({"runs": None, "ckpt": None, "fb_ckpts": [Path("/a")], "fb_labels": ["x", "y"]},
     "fb_labels=: 2 label(s) for 1 fb_ckpt="),
])
def test_plan_refuses_incomplete_options(tmp_path: Path, kwargs, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        plan(dataset=None, out_dir=tmp_path, no_solver=False, repeats=1, threads=1, **kwargs)


def test_all_with_only_a_fluidized_bed_checkpoint(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    called = []
    monkeypatch.setattr("neuraldem.bench.__main__.entry_point",
                        lambda name: (lambda args: called.append((name, args)) or 0))
    # a GNS map of other steps left from an earlier run does not fail an `all` that made no GNS map
    write_results("fb_stability", FB_STABILITY, command="test", path=tmp_path / "fb_stability.json", machine={})
    write_results("gns_stability", {**FB_STABILITY, "steps": 50}, command="test", path=tmp_path / "gns_stability.json",
                  machine={})
    assert suite.run_all(["fb_ckpt=[/fb/a.ckpt]", "no_solver=true", f"out_dir={tmp_path}"]) == 0
    assert [name for name, _ in called] == ["fb_speed", "fb_stability"]
    assert opts(called[0][1])["ckpt"] == "/fb/a.ckpt"  # each benchmark is run with key=value options
    assert not (tmp_path / "stability_map.png").exists()
    with pytest.raises(ConfigError, match="nothing to run"):
        suite.run_all([f"out_dir={tmp_path}"])


def test_render_fluidized_bed_results(tmp_path: Path):
    write_results("fb_speed", FB_SPEED, command="test", path=tmp_path / "fb_speed.json", machine={"cpu_model": "X"})
    write_results("fb_stability", FB_STABILITY, command="test", path=tmp_path / "fb_stability.json", machine={})
    assert bench_main(["render", f"out_dir={tmp_path}"]) == 0
    assert (tmp_path / "fb_speed.png").is_file() and (tmp_path / "fb_stability.png").is_file()
    md = (tmp_path / "fb_speed.md").read_text()
    assert "| DPMFoam, measured | torch | 1 | 170.0 | 160.0 | 1.000 | 0.800 | 170x | 200x |" in md


def _timing(wall: float, cpu: float, **notes) -> dict:
    return {"median_wall_s": wall, "median_cpu_s": cpu, "repeats": 1, "wall_s": [wall], "cpu_s": [cpu], **notes}


FB_SPEED = {
    "scene": "fb_small", "sim_id": "sim_0003", "inlet_velocity": 1.5, "n_particles": 1000, "cells": [12, 1, 30],
    "dt": 0.01, "surrogate_load_s": 0.3, "target_speedup": 100.0,
    "solver": {"DPMFoam, measured": _timing(170.0, 160.0, source="measured", simulated_s=0.3, spinup_s=0.2,
                                            stored_s=0.1)},
    "surrogate": {"1": _timing(1.0, 0.8, source="measured", steps_computed=300, diverged_at=None)},
    "side_by_side": [{"solver": "DPMFoam, measured", "surrogate_threads": 1, "solver_wall_s": 170.0,
                      "solver_cpu_s": 160.0, "surrogate_wall_s": 1.0, "surrogate_cpu_s": 0.8, "speedup_wall": 170.0,
                      "speedup_cpu": 200.0}],
}
FB_STABILITY = {
    "velocities": [1.0, 1.5], "steps": 100, "drift_limit_pct": 5.0,
    "series": [{"label": "m", "trained_velocity_range": [1.2, 1.6], "training_horizon_steps": 30, "n_failed": 1,
                "points": [{"inlet_velocity": 1.0, "failed": True, "steps_to_failure": 40, "steps_stable": 40,
                            "drift_pct_end": -7.0},
                           {"inlet_velocity": 1.5, "failed": False, "steps_to_failure": None, "steps_stable": 100,
                            "drift_pct_end": 0.5}]}],
}


def test_plan_with_fluidized_bed_runs(tmp_path: Path):
    steps = dict(plan(None, None, None, tmp_path, no_solver=False, repeats=2, threads=1, fb_runs=[Path("/fbruns")],
                      fb_dataset=Path("/fbd")))
    assert list(steps) == ["fb_speed_accuracy"]
    chart = opts(steps["fb_speed_accuracy"])
    assert chart["runs"] == "[/fbruns]" and chart["dataset"] == "/fbd" and "skip_solver" not in chart
    assert chart["out"] == str(tmp_path / "fb_speed_accuracy.json")
    # without the solver: the cheaper-DPMFoam points of an earlier chart if there is one, else none
    assert opts(dict(plan(None, None, None, tmp_path, no_solver=True, repeats=2, threads=1,
                          fb_runs=[Path("/r")]))["fb_speed_accuracy"])["skip_solver"] == "true"
    (tmp_path / "fb_speed_accuracy.json").write_text("{}")
    chart = opts(dict(plan(None, None, None, tmp_path, no_solver=True, repeats=2, threads=1,
                           fb_runs=[Path("/r")]))["fb_speed_accuracy"])
    assert chart["reuse_solver"] == str(tmp_path / "fb_speed_accuracy.json")


def test_plan_with_a_gns_of_the_bed(tmp_path: Path):
    steps = dict(plan(None, None, None, tmp_path, no_solver=True, repeats=1, threads=1, fb_ckpts=[Path("/fb.ckpt")],
                      gns_fb_ckpts=[Path("/gns.ckpt")], fb_dataset=Path("/fbd")))
    assert list(steps) == ["fb_speed", "fb_stability", "gns_stability"]  # the GNS map after the one it copies
    gns = opts(steps["gns_stability"])
    assert gns["ckpt"] == "[/gns.ckpt]" and gns["dataset"] == "/fbd"
    assert gns["like"] == str(tmp_path / "fb_stability.json")
    with pytest.raises(ConfigError, match="give fb_ckpt= too"):
        plan(None, None, None, tmp_path, no_solver=True, repeats=1, threads=1, fb_runs=[Path("/r")],
             gns_fb_ckpts=[Path("/gns.ckpt")])


def test_render_draws_field_surrogate_and_gns_in_one_map(tmp_path: Path):
    write_results("fb_stability", FB_STABILITY, command="test", path=tmp_path / "fb_stability.json", machine={})
    gns = {**FB_STABILITY, "series": [{**FB_STABILITY["series"][0], "label": "gns", "method": "gns"}]}
    write_results("gns_stability", gns, command="test", path=tmp_path / "gns_stability.json", machine={})
    assert bench_main(["render", f"out_dir={tmp_path}"]) == 0
    assert (tmp_path / "stability_map.png").is_file()
    # maps of other steps do not share a figure: render says why instead of drawing a misleading one
    write_results("gns_stability", {**gns, "steps": 50}, command="test", path=tmp_path / "gns_stability.json",
                  machine={})
    (tmp_path / "stability_map.png").unlink()
    assert bench_main(["render", f"out_dir={tmp_path}"]) == 2
    assert not (tmp_path / "stability_map.png").exists()


def test_plan_with_a_gns_of_the_hopper(tmp_path: Path):
    steps = dict(plan([Path("/runs")], Path("/c.ckpt"), None, tmp_path, no_solver=False, repeats=3, threads=1,
                      gns_hopper_ckpts=[Path("/g1.ckpt"), Path("/g2.ckpt")]))
    assert opts(steps["speed_accuracy"])["gns_ckpt"] == "[/g1.ckpt,/g2.ckpt]"
    assert "gns_ckpt" not in opts(steps["hopper_speed"])
    assert opts(steps["hopper_stability"])["gns_ckpt"] == "[/g1.ckpt,/g2.ckpt]"
    with pytest.raises(ConfigError, match="runs= and ckpt="):
        plan(None, None, None, tmp_path, no_solver=False, repeats=3, threads=1, fb_ckpts=[Path("/f.ckpt")],
             gns_hopper_ckpts=[Path("/g.ckpt")])
