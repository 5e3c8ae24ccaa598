"""The speed-accuracy chart: fronts per quantity, the scene check, and the command on real tiny runs."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from neuraldem.bench.__main__ import main as bench_main
from neuraldem.bench.speed_accuracy import chart, render_markdown, runs_of_one_scene
from neuraldem.errors import ConfigError
from neuraldem.scenes.hopper.analysis.scoring import HOPPER_ERRORS


def _point(method: str, label: str, t: float | None, drain: float, residual: float, outflow: float) -> dict:
    return {"method": method, "label": label, "time_to_answer_s": t,
            "errors": {"drainage_t95_pct_of_mean": drain, "drainage_mae_pct_of_mean": drain,
                       "residual_mae_pp": residual, "outflow_rel_err_pct": outflow}}


def test_fronts_per_quantity():
    points = [_point("surrogate", "small", 0.01, 20.0, 5.0, 30.0),
              _point("surrogate", "big", 0.05, 10.0, 6.0, 30.0),
              _point("liggghts", "fewer", 30.0, 15.0, 1.0, 10.0),
              _point("liggghts", "dt x5", None, math.nan, math.nan, math.nan)]  # failed: never on a front
    fronts = chart(points)
    assert fronts == {"drainage_t95_pct_of_mean": [0, 1], "drainage_mae_pct_of_mean": [0, 1], "residual_mae_pp": [0, 2],
                      "outflow_rel_err_pct": [0, 2]}
    text = render_markdown({"points": points, "pareto_front": fronts, "reference": {}})
    assert "| surrogate | small | 0.01 | 20.00 * | 20.00 * | 5.00 * | 30.00 * |" in text
    assert "| liggghts | dt x5 | - | failed | failed | failed | failed |" in text


def test_runs_of_several_scenes_need_a_choice():
    class Run:
        def __init__(self, name: str) -> None:
            self.data_name = name

    runs = [Run("hopper_small"), Run("hopper_tiny")]
    with pytest.raises(ConfigError, match=r"several datasets \['hopper_small', 'hopper_tiny'\]: pick one with "
                                          r"scene=NAME"):
        runs_of_one_scene(runs, None)
    assert runs_of_one_scene(runs, "hopper_tiny") == [runs[1]]
    with pytest.raises(ConfigError, match="no evaluated run of that dataset"):
        runs_of_one_scene(runs, "fb_tiny")


def test_surrogate_points_only(evaluated_runs: Path, tmp_path: Path):
    out = tmp_path / "sa.json"
    assert bench_main(["speed_accuracy", f"runs=[{evaluated_runs}]", "skip_solver=true", "repeats=1",
                       f"out={out}"]) == 0
    r = json.loads(out.read_text())["results"]
    assert [p["label"] for p in r["points"]] == ["multirun/0", "tiny"]
    assert all(p["time_to_answer_s"] > 0 and p["timing"]["repeats"] == 1 for p in r["points"])
    assert set(r["pareto_front"]) == set(HOPPER_ERRORS)
    assert out.with_suffix(".png").is_file() and "Pareto front" in out.with_suffix(".md").read_text()


@pytest.mark.solver
def test_with_a_cheaper_solver_and_reuse(evaluated_runs: Path, tmp_path: Path):
    out = tmp_path / "sa.json"
    argv = ["speed_accuracy", f"runs=[{evaluated_runs / 'tiny'}]", "repeats=1", "solver_variants=[fewer:0.5]",
            "solver_sims=1", f"workdir={tmp_path / 'w'}", f"out={out}"]
    assert bench_main(argv) == 0
    r = json.loads(out.read_text())["results"]
    solver = [p for p in r["points"] if p["method"] == "liggghts"]
    assert [p["variant"] for p in solver] == ["fewer:0.5"] and solver[0]["errors"]
    assert r["reference"]["source"].startswith("dataset manifest")  # no same:1 variant was run
    again = tmp_path / "again.json"
    assert bench_main(["speed_accuracy", f"runs=[{evaluated_runs / 'tiny'}]", "repeats=1", f"reuse_solver={out}",
                       f"out={again}"]) == 0
    r2 = json.loads(again.read_text())["results"]
    assert [p["label"] for p in r2["points"] if p["method"] == "liggghts"] == ["LIGGGHTS fewer x0.5"]
    assert any("not re-run" in n for n in r2["notes"])


def test_bad_inputs_are_one_line(evaluated_runs: Path, tmp_path: Path, capsys: pytest.CaptureFixture):
    out = [f"out={tmp_path / 'x.json'}"]
    assert bench_main(["speed_accuracy", f"runs=[{tmp_path}]", *out]) == 2
    assert "no evaluated hopper run" in capsys.readouterr().err
    assert bench_main(["speed_accuracy", f"runs=[{evaluated_runs}]", "solver_variants=[finer:2]", *out]) == 2
    assert "KIND:FACTOR" in capsys.readouterr().err
    assert bench_main(["speed_accuracy", f"runs=[{evaluated_runs}]", f"reuse_solver={tmp_path / 'none.json'}",
                       *out]) == 2
    assert "no results at" in capsys.readouterr().err
    assert not (tmp_path / "x.json").exists()


def test_cross_validated_points_and_the_seed_floor(tmp_path: Path):
    """`cv=`: the constant, the GP and the field model at their cross-validated errors, LIGGGHTS rerun with
    another seed as a point and as the floor line (hand-written CV file: a unit test of the assembly)."""
    def summary(err: float, t: float) -> dict:
        return {"n_folds": 5, "n_test": 40, "n_parameters": 100, "answer_s": {"mean": t, "std": 0.0},
                **{k: {"mean": err, "std": 1.0} for k in HOPPER_ERRORS}}

    cv = {"dataset": str(tmp_path / "hopper_small"), "folds": [],
          "summary": {"random": {"micro": {"constant": summary(30.0, 1e-4), "gp": summary(10.0, 3e-3),
                                           "field model": summary(8.0, 4.0)}}},
          "seed_floor": {"n_sets": 10, "n_seeds": 3, "answer_s": {"mean": 60.0, "std": float("nan")},
                         **{k: {"mean": 2.0, "std": float("nan")} for k in HOPPER_ERRORS}}}
    path = tmp_path / "cv.json"
    path.write_text(json.dumps(cv))
    out = tmp_path / "sa.json"
    assert bench_main(["speed_accuracy", f"cv={path}", "skip_solver=true", f"out={out}"]) == 0
    r = json.loads(out.read_text())["results"]
    methods = {p["method"]: p for p in r["points"]}
    assert set(methods) == {"constant (training mean)", "Gaussian process", "field model (CV)",
                            "LIGGGHTS, another packing seed"}
    assert methods["Gaussian process"]["errors"]["drainage_t95_pct_of_mean"] == 10.0
    assert r["floor"]["residual_mae_pp"] == 2.0 and out.with_suffix(".png").is_file()
    assert bench_main(["speed_accuracy", "skip_solver=true", f"out={out}"]) == 2  # nothing to chart


def test_the_query_budget_is_a_curve_at_the_chosen_stride(tmp_path: Path):
    """`query_budget=`: the field model's errors over shares of its query points at the chosen time stride, cheapest
    first, drawn and tabled beside the points; a file of another benchmark is refused by name."""
    from neuraldem.bench.report import write_results
    from neuraldem.errors import DataError

    def row(share: float, stride: int, t: float, err: float) -> dict:
        return {"query_points": share, "time_stride": stride, "answer_s": t,
                "errors": {**{k: err for k in HOPPER_ERRORS}, "flow_regime_accuracy": 0.8}}

    budget = write_results("query_budget", {
        "model": "m", "runs": ["a", "b", "c"], "chosen": {"query_points": 0.5, "time_stride": 4},
        "budgets": [row(1.0, 1, 4.0, 3.0), row(1.0, 4, 1.0, 3.1), row(0.5, 4, 0.5, 3.2), row(0.25, 8, 0.1, 9.0)]},
        command="test", path=tmp_path / "query_budget.json")
    cv = tmp_path / "cv.json"
    cv.write_text(json.dumps({"dataset": "d", "folds": [], "summary": {"random": {"micro": {"gp": {
        "n_folds": 5, "answer_s": {"mean": 3e-3}, **{k: {"mean": 10.0, "std": 1.0} for k in HOPPER_ERRORS}}}}}}))
    out = tmp_path / "sa.json"
    assert bench_main(["speed_accuracy", f"cv={cv}", f"query_budget={budget}", "skip_solver=true",
                       f"out={out}"]) == 0
    curve = json.loads(out.read_text())["results"]["curves"][0]
    assert [c["query_points"] for c in curve["points"]] == [0.5, 1.0]  # stride 4 only, cheapest first
    assert curve["points"][0]["errors"]["outflow_rel_err_pct"] == 3.2
    assert "| 0.5 (chosen) | 0.5 |" in out.with_suffix(".md").read_text()
    with pytest.raises(DataError, match="holds results of benchmark"):
        from neuraldem.bench.speed_accuracy import budget_curve

        budget_curve(out)
