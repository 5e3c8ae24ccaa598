"""Runs are named by their folder under the searched one; runs of one name in two searched folders (two seeds
of one sweep) get the folder's name in front, so tables and charts never show two rows of one label."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.errors import DataError
from neuraldem.eval.run_results import find_results


def _evaluated(run: Path, value: float) -> None:
    (run / "evaluation").mkdir(parents=True)
    (run / "evaluation" / "metrics.json").write_text(json.dumps({"value": value}))


def test_runs_named_by_their_path_and_told_apart_across_folders(tmp_path: Path):
    _evaluated(tmp_path / "seed0" / "fb_tiny" / "noise_pf", 1.0)
    _evaluated(tmp_path / "seed0" / "fb_base" / "grid_only", 2.0)
    _evaluated(tmp_path / "seed1" / "fb_tiny" / "noise_pf", 3.0)
    _evaluated(tmp_path / "single", 4.0)  # a run folder given itself
    found = find_results([tmp_path / "seed0", tmp_path / "seed1", tmp_path / "single"])
    assert {r["run"]: r["value"] for r in found} == {
        "fb_base/grid_only": 2.0, "seed0/fb_tiny/noise_pf": 1.0, "seed1/fb_tiny/noise_pf": 3.0, "single": 4.0}
    assert [r["run"] for r in find_results([tmp_path / "seed1"])] == ["fb_tiny/noise_pf"]  # alone: no prefix


def test_nothing_evaluated_is_one_clear_error(tmp_path: Path):
    with pytest.raises(DataError, match="evaluate=true"):
        find_results([tmp_path])
