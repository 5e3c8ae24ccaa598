"""Collecting evaluated runs: sizes and errors read right, and every kind of bad input is one clear error."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from neuraldem.errors import DataError
from neuraldem.scenes.hopper.bench.runs import HOPPER_ERRORS, collect_runs, run_folders, time_to_answer


def test_runs_are_found_with_errors_and_size(evaluated_runs: Path):
    runs, notes = collect_runs([evaluated_runs])
    assert [r.label for r in runs] == ["multirun/0", "tiny"] and notes == []
    run = runs[1]
    metrics = json.loads((run.run_dir / "evaluation" / "metrics.json").read_text())
    assert run.errors == {k: metrics["aggregate"][k] for k in HOPPER_ERRORS}
    assert run.data_name == "hopper_tiny" and run.split == "random"
    assert run.size["n_latent_tokens"] == 8 and run.size["train_queries"] == 32 and run.size["parameters"] > 1000
    point = run.as_point()
    assert point["method"] == "surrogate" and point["time_to_answer_s"] is None  # not timed yet


def test_time_to_answer_is_a_full_trajectory(evaluated_runs: Path):
    run = collect_runs([evaluated_runs / "tiny"])[0][0]
    timing = time_to_answer(run, repeats=2, threads=1)
    assert len(timing.samples) == 2 and timing.median.wall_s > 0
    assert timing.notes["question"]["n_points"] == 500 and timing.notes["threads"] == 1


def test_no_runs_found(tmp_path: Path):
    with pytest.raises(DataError, match="no evaluated hopper run under"):
        collect_runs([tmp_path])
    with pytest.raises(DataError, match="no such folder"):
        collect_runs([tmp_path / "missing"])


def test_run_folder_without_metrics(evaluated_runs: Path, tmp_path: Path):
    root = tmp_path / "grid"
    shutil.copytree(evaluated_runs / "tiny", root / "done")
    (root / "training" / "checkpoints").mkdir(parents=True)
    assert run_folders([root]) == ([root / "done"], [root / "training"])
    with pytest.raises(DataError, match=r"1 run folder\(s\) without evaluation/metrics.json .*training.*"
                                        r"neuraldem evaluate ckpt=.*skip_unevaluated=true"):
        collect_runs([root])
    runs, notes = collect_runs([root], skip_unevaluated=True)
    assert [r.label for r in runs] == ["done"] and "not evaluated" in notes[0]


def test_broken_metrics_name_the_file_and_field(evaluated_runs: Path, tmp_path: Path):
    run = tmp_path / "run"
    shutil.copytree(evaluated_runs / "tiny", run)
    metrics = run / "evaluation" / "metrics.json"
    good = json.loads(metrics.read_text())
    metrics.write_text("{not json")
    with pytest.raises(DataError, match="metrics.json is not valid JSON"):
        collect_runs([run])
    metrics.write_text(json.dumps({k: v for k, v in good.items() if k != "aggregate"}))
    with pytest.raises(DataError, match="no 'aggregate' field"):
        collect_runs([run])
    moved = {**good, "checkpoint": "/nowhere/else.ckpt"}
    metrics.write_text(json.dumps(moved))
    with pytest.raises(DataError, match="field 'checkpoint' = '/nowhere/else.ckpt' does not exist"):
        collect_runs([run])
    fb = {**good, "aggregate": {"solid_fraction_mean_rel_l2": 0.1}}
    metrics.write_text(json.dumps(fb))
    with pytest.raises(DataError, match="no evaluated hopper run"):
        collect_runs([run])
