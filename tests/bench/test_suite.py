"""`all` runs the four hopper benchmarks with consistent options; `render` redraws from results files."""

from __future__ import annotations

from pathlib import Path

import pytest

from neuraldem.bench import hopper_scaling
from neuraldem.bench.__main__ import main as bench_main
from neuraldem.bench.report import write_results
from neuraldem.bench.suite import plan
from tests.bench.test_hopper_scaling import HAND_MADE


def test_plan_measures_everything_by_default(tmp_path: Path):
    steps = dict(plan([Path("/runs")], Path("/c.ckpt"), None, tmp_path, no_solver=False, repeats=5, threads=1))
    assert list(steps) == ["hopper_speed", "hopper_scaling", "speed_accuracy", "right_sizing"]
    assert "--reuse-dataset" not in steps["hopper_speed"] and "--skip-solver" not in steps["speed_accuracy"]
    assert steps["right_sizing"][:2] == ["--from", str(tmp_path / "speed_accuracy.json")]
    assert steps["hopper_speed"][steps["hopper_speed"].index("--repeats") + 1] == "5"


def test_plan_without_solver_reuses_what_exists(tmp_path: Path):
    (tmp_path / "hopper_scaling.json").write_text("{}")
    steps = dict(plan([Path("/runs")], Path("/c.ckpt"), Path("/d"), tmp_path, no_solver=True, repeats=3, threads=2,
                      skip_unevaluated=True))
    assert "--reuse-dataset" in steps["hopper_speed"]
    assert steps["hopper_scaling"][-2:] == ["--reuse-solver", str(tmp_path / "hopper_scaling.json")]
    assert steps["speed_accuracy"][-1] == "--skip-solver"  # nothing earlier to reuse
    assert "--skip-unevaluated" in steps["speed_accuracy"]
    assert "/d" in steps["speed_accuracy"]


def test_all_without_solver_then_render(evaluated_runs: Path, tiny_checkpoint: Path, hopper_tiny_dataset: Path,
                                        tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    # `all` uses the scaling sweep's defaults, sized for the real measurement: shrink them for the test
    monkeypatch.setattr(hopper_scaling, "DEFAULT_QUERIES", (50,))
    monkeypatch.setattr(hopper_scaling, "DEFAULT_TOKENS", (4,))
    argv = ["all", "--runs", str(evaluated_runs / "tiny"), "--ckpt", str(tiny_checkpoint), "--dataset",
            str(hopper_tiny_dataset), "--no-solver", "--repeats", "1", "--out-dir", str(tmp_path)]
    assert bench_main(argv) == 0
    names = {"hopper_speed.json", "hopper_speed.md", "hopper_scaling.json", "hopper_scaling.png",
             "speed_accuracy.json", "speed_accuracy.png", "speed_accuracy.md", "right_sizing.json", "right_sizing.md"}
    assert names <= {p.name for p in tmp_path.iterdir()}
    for name in ("hopper_scaling.png", "speed_accuracy.png", "right_sizing.md"):
        (tmp_path / name).unlink()
    assert bench_main(["render", "--out-dir", str(tmp_path)]) == 0
    assert (tmp_path / "hopper_scaling.png").is_file() and (tmp_path / "right_sizing.md").is_file()


def test_render_from_a_results_file(tmp_path: Path):
    write_results("hopper_scaling", HAND_MADE, command="test", path=tmp_path / "hopper_scaling.json", machine={})
    assert bench_main(["render", "--out-dir", str(tmp_path)]) == 0
    assert (tmp_path / "hopper_scaling.png").is_file()


def test_render_with_nothing_to_render(tmp_path: Path, capsys: pytest.CaptureFixture):
    assert bench_main(["render", "--out-dir", str(tmp_path)]) == 2
    assert "no benchmark results in" in capsys.readouterr().err
