"""Right-sizing on hand-made tables with known picks, and from a speed_accuracy results file."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from neuraldem.bench.__main__ import main as bench_main
from neuraldem.bench.report import write_results
from neuraldem.bench.right_sizing import render_markdown, right_size
from neuraldem.errors import ConfigError, DataError

METRIC = "drainage_t95_pct_of_mean"


def _row(label: str, error: float, parameters: int, tokens: int = 16, queries: int = 512, t: float = 0.1,
         conditioning: tuple[str, ...] = ("t", "alpha", "mu_s", "mu_r")) -> dict:
    return {"label": label, "data_name": "hopper_small", "split": "random", "conditioning": list(conditioning),
            "errors": {METRIC: error}, "size": {"parameters": parameters, "n_latent_tokens": tokens,
                                               "train_queries": queries}, "time_to_answer_s": t}


TABLE = [
    _row("huge", 10.0, 3_000_000, 64),    # best
    _row("base", 10.9, 800_000, 16),      # within 10 % (<= 11.0)
    _row("base-8tok", 10.9, 800_000, 8),  # same parameters, fewer tokens -> the pick
    _row("tiny", 11.5, 100_000, 8),       # smallest, but 15 % worse
    _row("broken", math.nan, 50_000, 4),  # no finite error: left out
    _row("theta", 30.0, 10_000, 4, conditioning=("t", "alpha", "theta")),  # another task
]


def test_smallest_within_ten_percent():
    picks = right_size(TABLE, METRIC)
    main, other = sorted(picks, key=lambda p: len(p["conditioning"]), reverse=True)
    assert main["best"]["label"] == "huge" and main["threshold"] == pytest.approx(11.0)
    assert main["pick"]["label"] == "base-8tok"
    assert main["within_tolerance"] == ["base-8tok", "base", "huge"] and main["left_out"] == ["broken"]
    assert other["pick"]["label"] == "theta"  # alone in its task
    assert right_size(TABLE, METRIC, tolerance=0.20)[0]["pick"]["label"] == "tiny"
    assert "Pick: **base-8tok**" in render_markdown(picks)


def test_seeds_of_one_size_are_averaged_before_picking():
    # tiny alone (seed 0) looks within 10 % of base, but its second seed is much worse: the mean decides
    rows = [_row("base", 10.0, 800_000), _row("base_seed1", 12.0, 800_000, t=0.3),
            _row("tiny", 10.5, 100_000, 8), _row("tiny_seed1", 15.5, 100_000, 8)]
    pick = right_size(rows, METRIC)[0]
    assert pick["best"]["label"] == "base + base_seed1 (mean of 2)" and pick["best"]["error"] == pytest.approx(11.0)
    assert pick["pick"] == pick["best"] and pick["best"]["error_range"] == [10.0, 12.0]
    assert pick["best"]["time_to_answer_s"] == pytest.approx(0.2)  # median of the repeats
    assert [c["error"] for c in pick["candidates"]] == [pytest.approx(13.0), pytest.approx(11.0)]
    assert "(10.00 - 12.00)" in render_markdown([pick])
    # without the second seeds tiny would be picked
    assert right_size(rows[::2], METRIC)[0]["pick"]["label"] == "tiny"


def test_bad_tables():
    with pytest.raises(DataError, match="no run has a finite"):
        right_size([_row("broken", math.nan, 1)], METRIC)
    with pytest.raises(ConfigError, match="metric"):
        right_size(TABLE, "accuracy")
    with pytest.raises(ConfigError, match="tolerance"):
        right_size(TABLE, METRIC, tolerance=-0.1)


def test_from_a_speed_accuracy_file(tmp_path: Path):
    points = [{**r, "method": "surrogate"} for r in TABLE] + [{"method": "liggghts", "label": "fewer"}]
    src = write_results("speed_accuracy", {"points": points}, command="test", path=tmp_path / "sa.json",
                        machine={})
    out = tmp_path / "rs.json"
    assert bench_main(["right_sizing", f"from_file={src}", f"out={out}"]) == 0
    picks = json.loads(out.read_text())["results"]["picks"]
    assert {p["pick"]["label"] for p in picks} == {"base-8tok", "theta"}
    assert "| base-8tok | 800,000 | 8 | 512 | 0.1 | 10.90 | pick |" in out.with_suffix(".md").read_text()


def test_all_quantities_at_once(tmp_path: Path):
    rows = [{**r, "method": "surrogate",
             "errors": {**r["errors"], "outflow_rel_err_pct": 1.0 / r["size"]["parameters"]}}
            for r in TABLE]
    src = write_results("speed_accuracy", {"points": rows}, command="test", path=tmp_path / "sa.json", machine={})
    out = tmp_path / "rs.json"
    assert bench_main(["right_sizing", f"from_file={src}", "metric=all", f"out={out}"]) == 0
    picks = json.loads(out.read_text())["results"]["picks"]
    by_metric = {(p["metric"], tuple(p["conditioning"])): p["pick"]["label"] for p in picks}
    main = ("t", "alpha", "mu_s", "mu_r")
    assert by_metric[(METRIC, main)] == "base-8tok"
    assert by_metric[("outflow_rel_err_pct", main)] == "huge"  # the largest is far the most accurate there
    assert not any(m == "residual_mae_pp" for m, _ in by_metric)  # no run has it: skipped, not an error


def test_wrong_results_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture):
    other = write_results("hopper_speed", {}, command="test", path=tmp_path / "speed.json", machine={})
    assert bench_main(["right_sizing", f"from_file={other}", f"out={tmp_path / 'rs.json'}"]) == 2
    assert "holds results of benchmark 'hopper_speed', not 'speed_accuracy'" in capsys.readouterr().err


def test_a_scalar_baseline_is_a_candidate(tmp_path: Path):
    """A Gaussian process within 10 % of the best field model answers the three numbers with far fewer
    parameters: it is the pick ('no more model than the scene needs'); the constant, 30 % off, is not."""
    points = [{**r, "method": "surrogate"} for r in TABLE]
    points.append({**_row("gp, 5-fold CV", 10.5, 300, tokens=None, queries=None, t=0.003),
                   "method": "Gaussian process"})
    points.append({**_row("constant", 13.0, 15, tokens=None, queries=None, t=1e-4),
                   "method": "constant (training mean)"})
    src = write_results("speed_accuracy", {"points": points}, command="test", path=tmp_path / "sa.json", machine={})
    out = tmp_path / "rs.json"
    assert bench_main(["right_sizing", f"from_file={src}", f"out={out}"]) == 0
    pick = next(p for p in json.loads(out.read_text())["results"]["picks"] if p["conditioning"][-1] == "mu_r")
    assert pick["pick"]["label"] == "gp, 5-fold CV"
