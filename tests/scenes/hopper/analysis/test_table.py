"""The Table-4 collector on hand-written metrics files (a unit test of the assembly, not of a model)."""

from __future__ import annotations

import json
from pathlib import Path

from tests.helpers import run_module


def _write(folder: Path, split: str, conditioning: list[str], drainage: float) -> None:
    ev = folder / "evaluation"
    ev.mkdir(parents=True)
    agg = {"n_sims": 3, "drainage_mae_s": drainage, "drainage_mae_pct_of_mean": 10.0, "drainage_t95_pct_of_mean": 8.0,
           "residual_mae_pp": 1.0,
           "outflow_rel_err_pct": 5.0, "flow_regime_accuracy": 1.0, "transport_mse": 0.01, "residence_mse": 0.001}
    (ev / "metrics.json").write_text(json.dumps({
        "split": split, "conditioning": conditioning, "aggregate": agg, "table_row": f"| row {drainage} |",
        "checkpoint": "/x/last.ckpt", "dataset": "/d", "machine": {}, "command": "c", "date_utc": "d"}))


def test_rows_ordered_like_the_paper_and_split_by_split(tmp_path: Path):
    _write(tmp_path / "0", "random", ["t", "alpha", "theta", "repose"], 0.4)
    _write(tmp_path / "1", "random", ["t", "alpha", "mu_s", "mu_r"], 0.2)
    _write(tmp_path / "2", "band", ["t", "alpha", "mu_s", "mu_r"], 0.9)
    out = tmp_path / "table.md"
    proc = run_module("neuraldem", "report", "hopper-table", f"folders=[{tmp_path}]", f"out={out}")
    assert proc.returncode == 0, proc.stderr
    text = out.read_text()
    assert text.index("split: band") < text.index("split: random")
    random_part = text[text.index("split: random"):]
    assert random_part.index("| row 0.2 |") < random_part.index("| row 0.4 |")
    assert len(json.loads(out.with_suffix(".json").read_text())) == 3


def test_nothing_found_is_one_clear_line(tmp_path: Path):
    proc = run_module("neuraldem", "report", "hopper-table", f"folders=[{tmp_path}]", f"out={tmp_path / 't.md'}")
    assert proc.returncode == 2 and "no evaluation/metrics.json" in proc.stderr
    assert proc.stderr.startswith("neuraldem: error: ") and proc.stderr.count("\n") == 1, proc.stderr
