"""The fluidized-bed run table from real evaluations of the tiny model (one of them with a divergence
injected at step 30), and its clear error when a folder holds no fluidized-bed evaluation."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.scenes.fluidized_bed.analysis.evaluation import evaluate_checkpoint
from neuraldem.scenes.fluidized_bed.surrogate.rollout import ModelStepper
from tests.helpers import run_module
from tests.scenes.fluidized_bed.surrogate.test_rollout import Inject, _nan

pytestmark = pytest.mark.solver


def test_one_row_per_run_and_per_velocity_with_stability(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path,
                                                         tmp_path: Path):
    def diverging(module, velocity):
        return Inject(ModelStepper(module, velocity), at=30, spoil=_nan)

    for name, make in (("steady", None), ("broken", diverging)):
        with pytest.warns(UserWarning, match="outside the range"):
            evaluate_checkpoint(fb_tiny_checkpoint, tmp_path / "runs" / name / "evaluation", fb_tiny_dataset.parent,
                                horizons=[1, 3], vtk=False, progress=False, make_stepper=make)
    out = tmp_path / "table.md"
    proc = run_module("neuraldem", "report", "fb-table", f"folders=[{tmp_path / 'runs'}]", f"out={out}")
    assert proc.returncode == 0, proc.stderr
    rows = {line.split(" | ")[0].lstrip("| "): line for line in out.read_text().splitlines()
            if line.startswith("| steady | 2.042 (extrapolated)")}  # the per-velocity row
    summary = [line for line in out.read_text().splitlines() if line.startswith("| broken |")]
    assert len(summary) == 4  # one summary row, one per-velocity row, the same two against the pooled reference
    assert summary[0].endswith("| 1/1 | 0/1 |")  # stable for 1x (20 steps), not 3x
    assert summary[1].endswith("| 30 |") and "2.042 (extrapolated)" in summary[1]
    # pooled: the one CFD-DEM run of the test velocity (20 steps from snapshot 1), the 30 steps rolled out
    assert summary[2].startswith("| broken | 2.042 | 1 (20) | 30 |")
    tm, sd, lacey, total = (float(c) for c in summary[2].strip("| ").split(" | ")[4:8])
    assert total == pytest.approx(tm + sd + lacey, abs=2e-3) and summary[3].startswith("| broken | 1 |")
    saved = json.loads(out.with_suffix(".json").read_text())
    walls = next(r for r in saved if r["run"] == "broken")["trajectories"][0]["pooled"]["structure"]
    assert summary[2].endswith(f"| {walls['std_wall_share_pred']:.3f} / {walls['std_wall_share_truth']:.3f} |")
    steady = next(r for r in saved if r["run"] == "steady")["trajectories"][0]["stability"]["steps_to_divergence"]
    assert rows["steady"].endswith(f"| {'none' if steady is None else steady} |")
    assert sorted(r["run"] for r in saved) == ["broken", "steady"]
    assert all(r["training"]["push_forward_steps"] == 1 and r["training"]["parameters"] > 0 for r in saved)


def test_folder_without_fluidized_bed_results_is_one_clear_line(tmp_path: Path):
    ev = tmp_path / "hopper_run" / "evaluation"
    ev.mkdir(parents=True)
    (ev / "metrics.json").write_text(json.dumps({"split": "random", "aggregate": {}}))
    proc = run_module("neuraldem", "report", "fb-table", f"folders=[{tmp_path}]", f"out={tmp_path / 't.md'}")
    assert proc.returncode == 2 and "no fluidized-bed evaluation" in proc.stderr
    assert "run neuraldem evaluate ckpt=..." in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_long_trajectories_get_their_own_table_and_stay_out_of_the_summary(fb_tiny_checkpoint: Path,
                                                                          fb_tiny_dataset: Path, tmp_path: Path):
    """A real evaluation of the tiny model, plus (edited in, as a 30-s trajectory would come) a copy of its
    trajectory compared over 10x the training horizon with other errors, and the options of an EMA, mirrored
    run: the summary row keeps the short trajectory's numbers, the long one is listed in its own table."""
    from neuraldem.scenes.fluidized_bed.analysis.table import main as table_main

    folder = tmp_path / "runs" / "ema_mirror" / "evaluation"
    with pytest.warns(UserWarning, match="outside the range"):
        result = evaluate_checkpoint(fb_tiny_checkpoint, folder, fb_tiny_dataset.parent, horizons=[1],
                                     vtk=False, progress=False)
    assert result["training"]["weights"] == "as trained" and result["training"]["mirror"] is False
    short = result["trajectories"][0]
    long = json.loads(json.dumps(short))
    assert short["truth_steps"] == short["window_steps"]  # the tiny trajectories are training-length
    long["window_steps"] = long["truth_steps"] = 10 * result["training_horizon_steps"]
    long["rel_l2_full"]["solid_fraction_mean"] = 0.777  # the long table: each whole series against the other
    result["trajectories"].append(long)
    result["training"] |= {"weights": "EMA", "mirror": True}
    result["stability"]["mirror_alternate"] = True
    (folder / "metrics.json").write_text(json.dumps(result))
    out = tmp_path / "table.md"
    assert table_main([f"folders=[{tmp_path / 'runs'}]", f"out={out}"]) == 0
    lines = out.read_text().splitlines()
    summary = next(line for line in lines if line.startswith("| ema_mirror | "))
    cells = [c.strip() for c in summary.strip("|").split("|")]
    assert "mirror" in cells[2] and "EMA" in cells[2] and "mirror-alternating rollout" in cells[2]
    assert cells[3] == f"{short['rel_l2']['solid_fraction_mean']:.3f}"  # not averaged with the long one
    assert cells[-1] == "1/1"  # one trajectory counted
    start = next(i for i, line in enumerate(lines) if line.startswith("Against the long CFD-DEM trajectories"))
    end = next(i for i, line in enumerate(lines) if line.startswith("Against every CFD-DEM trajectory"))
    long_rows = [line for line in lines[start:end] if line.startswith("| ema_mirror |")]
    assert len(long_rows) == 1 and "| 0.777 |" in long_rows[0]
    lr = long["structure"]  # the left-right columns: profile / lateral, lean rollout / CFD-DEM
    assert long_rows[0].endswith(f"| {lr['mean_profile_rel_l2']:.3f} / {lr['mean_lateral_rel_l2']:.3f} "
                                 f"| {lr['std_lean_pred']:+.3f} / {lr['std_lean_truth']:+.3f} |")
