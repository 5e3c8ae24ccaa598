"""`neuraldem bench whatif` on the tiny shipped hopper model: the answer times of predict's own path (in the
process and as whole commands) written with their command; the budgeted answer is the one predict gives."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from tests.conftest import TINY


def test_answer_times_follow_predicts_path(use_tiny_model: Path, tmp_path: Path):
    from neuraldem.scenes.hopper.bench.predict_timing import main
    from neuraldem.scenes.hopper.whatif import ANSWER_BUDGET

    out = tmp_path / "whatif.json"
    assert main([f"model={TINY}", "points=0", "repeats=1", f"out={out}"]) == 0
    times = json.loads(out.read_text())["results"]["answer_times"]
    assert times["budget"] == ANSWER_BUDGET.as_dict()
    for key in ("gp_in_process", "field_numbers_in_process", "field_full_query_in_process",
                "predict_command_to_numbers", "predict_command_with_pictures", "predict_command_gp_only"):
        assert times[key]["repeats"] == 1 and times[key]["median_wall_s"] > 0, key
    # the numbers are printed before the pictures are made
    assert times["predict_command_to_numbers"]["median_wall_s"] <= times["predict_command_with_pictures"][
        "median_wall_s"]
    assert f"neuraldem bench whatif model={TINY}" in out.with_suffix(".md").read_text()


def test_a_predict_command_that_fails_is_named(tmp_path: Path):
    from neuraldem.bench.timing import command_times

    with pytest.raises(RuntimeError, match="printed no numbers"):
        command_times([sys.executable, "-c", "print('no table')"], 1)
