"""The refill table collector on hand-written metrics files (a unit test of the assembly, not of a model)."""

from __future__ import annotations

import json
from pathlib import Path

from tests.helpers import run_module


def _agg(transport_mse: float, residence_mse: float) -> dict:
    return {"n_sims": 3, "rtd_answer_cpu_s": 2.0, "solver_cpu_s": 600.0, "layer_fraction_error": 0.1,
            "label_agreement": 0.8, "transport_mse": transport_mse, "residence_mse": residence_mse,
            "rtd_wasserstein_s": 0.3, "rtd_median_error_s": -0.2}


def _write(folder: Path, t_refs: list[float], horizon: float) -> None:
    folder.mkdir(parents=True)
    (folder / "metrics.json").write_text(json.dumps({
        "conditioning": ["dt_ref", "alpha"], "window": 5.0, "horizon": horizon,
        "aggregate": _agg(0.0004, 0.01), "persistence": _agg(0.01, 0.04),
        "simulations": [{"t_ref": t} for t in t_refs], "checkpoint": "/x.ckpt", "dataset": "/d"}))


def test_rows_give_rms_values_model_beside_persistence(tmp_path: Path):
    _write(tmp_path / "hopper_tiny" / "evaluation", [15.0, 15.0, 15.0], 5.0)
    _write(tmp_path / "hopper_tiny" / "evaluation_tref0", [0.0] * 3, 5.0)
    (tmp_path / "hopper_tiny" / "other").mkdir()
    (tmp_path / "hopper_tiny" / "other" / "metrics.json").write_text(json.dumps({"aggregate": {}}))
    out = tmp_path / "table.md"
    proc = run_module("neuraldem", "report", "refill-table", f"folders=[{tmp_path}]", f"out={out}")
    assert proc.returncode == 0, proc.stderr
    text = out.read_text()
    # transport: sqrt(0.0004) = 2 % of the box (persistence sqrt(0.01) = 10 %); residence 5 s x sqrt(0.01) = 0.5 s
    assert ("| hopper_tiny | test | dt_ref, alpha | 15 | 5 | 0.100 / 0.100 | 0.80 / 0.80 | 2.0 / 10.0 "
            "| 0.50 / 1.00 |") in text
    assert "| hopper_tiny | test | dt_ref, alpha | 0 | 5 |" in text
    assert "| hopper_tiny | 5 | 15 | 2.00 | 600 | 300x |" in text
    assert len(json.loads(out.with_suffix(".json").read_text())) == 2


def test_nothing_found_is_one_clear_line(tmp_path: Path):
    proc = run_module("neuraldem", "report", "refill-table", f"folders=[{tmp_path}]", f"out={tmp_path / 't.md'}")
    assert proc.returncode == 2 and "no refill evaluation" in proc.stderr


def test_runs_of_one_name_in_two_folders_are_told_apart(tmp_path: Path):
    _write(tmp_path / "study" / "hopper_tiny" / "evaluation", [15.0], 5.0)
    _write(tmp_path / "study_seed1" / "hopper_tiny" / "evaluation", [15.0], 5.0)
    out = tmp_path / "table.md"
    folders = f"folders=[{tmp_path / 'study'},{tmp_path / 'study_seed1'}]"
    proc = run_module("neuraldem", "report", "refill-table", folders, f"out={out}")
    assert proc.returncode == 0, proc.stderr
    text = out.read_text()
    assert "| study/hopper_tiny | test |" in text and "| study_seed1/hopper_tiny | test |" in text
