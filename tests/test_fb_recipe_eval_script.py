"""scripts/fb_recipe_eval.sh: a bed recipe's whole evaluation as commands (a fake python records them instead of running
them): both seeds trained and chosen with the same rollout options and the long validation set, the chosen
checkpoints scored on test, baselines, tables, stability map and speed; a missing long validation set and an
unknown rollout option stop it before anything runs."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "fb_recipe_eval.sh"


def _run(tmp_path: Path, **extra: str) -> tuple[subprocess.CompletedProcess, list[list[str]]]:
    calls = tmp_path / "calls.txt"
    fake = tmp_path / "python"
    fake.write_text(f'#!/bin/sh\necho "$@" >> {calls}\n')
    fake.chmod(0o755)
    env = {**os.environ, "PYTHON": str(fake), "NEURALDEM_DATA": str(tmp_path / "data"), **extra}
    proc = subprocess.run(["bash", str(SCRIPT), str(tmp_path / "runs"), "trainer.max_steps=7"], env=env,
                          capture_output=True, text=True, timeout=120, check=False)
    lines = calls.read_text().splitlines() if calls.exists() else []
    return proc, [line.split() for line in lines]


def test_the_protocol_for_two_seeds(tmp_path: Path):
    longval = tmp_path / "data" / "datasets" / "fb_small_longval"
    longval.mkdir(parents=True)
    (longval / "manifest.json").write_text("{}")
    proc, calls = _run(tmp_path)
    assert proc.returncode == 0, proc.stderr
    runs = tmp_path / "runs"
    train = sorted((c for c in calls if c[1] == "neuraldem.train"), key=lambda c: "seed=1" in c)
    assert len(train) == 2 and "seed=0" in train[0] and "seed=1" in train[1]
    assert all("experiment=fb" in c and "trainer.max_steps=7" in c for c in train)
    select = [c for c in calls if c[1] == "neuraldem.scenes.fluidized_bed.surrogate.selection"]
    assert len(select) == 2
    for c in select:
        flags = " ".join(c)
        assert "rollout.rollout_noise=3 rollout.advection_correction=1 rollout.mirror_alternate=true" in flags
        assert f"--long-val {longval}" in flags and "--from-step 4500" in flags and "--seeds 0 1" in flags
    folder = "full+rollout_noise-3+advection_correction-1+mirror_alternate-true+sel"  # fb_ablation.sh's
    chosen = [runs / f"seed{s}" / folder / "selected.ckpt" for s in (0, 1)]
    tests = [c for c in calls if c[1] == "neuraldem.evaluate" and any(a.startswith(f"ckpt={chosen[0]}") for a in c)]
    assert len(tests) == 2 and sum("part=val" in c for c in tests) == 1  # val and test of the chosen one
    baselines = [c for c in calls if c[1] == "neuraldem.scenes.fluidized_bed.analysis.baselines"]
    assert [c[c.index("--part") + 1] for c in baselines] == ["test", "val"]
    table = [c for c in calls if c[1] == "neuraldem.scenes.fluidized_bed.analysis.table" and f"{runs}/table.md" in c]
    assert table and table[0][2:5] == [f"{runs}/seed0", f"{runs}/seed1", f"{runs}/baselines"]
    stab, fine = [c for c in calls if c[1:3] == ["neuraldem.bench", "fb_stability"]]
    for c in (stab, fine):
        assert [str(p) for p in chosen] == c[c.index("--ckpt") + 1:c.index("--ckpt") + 3]
        assert {"rollout.mirror_alternate=true", "rollout.advection_correction=1", "--steps"} <= set(c)
    assert "--velocity-step" not in stab and fine[fine.index("--velocity-step") + 1] == "0.005"
    assert fine[fine.index("--out") + 1] == f"{runs}/fb_stability_fine.json"
    (speed,) = [c for c in calls if c[1:3] == ["neuraldem.bench", "fb_speed"]]
    assert str(chosen[0]) in speed and {"rollout.rollout_noise=3", "rollout.mirror_alternate=true"} <= set(speed)
    assert not any(a.startswith("rollout.advection") for a in speed)  # no step cost: fb_speed does not take it
    assert "--threads" in speed and speed[speed.index("--threads") + 1] == "1"


def test_another_base_variant_is_trained_chosen_and_scored(tmp_path: Path):
    proc, calls = _run(tmp_path, LONG_VAL="", SEEDS="0", BASE="cond10")
    assert proc.returncode == 0, proc.stderr
    (train,) = [c for c in calls if c[1] == "neuraldem.train"]
    assert "model.net.scalar_coord_scale=10" in train
    (select,) = [c for c in calls if c[1] == "neuraldem.scenes.fluidized_bed.surrogate.selection"]
    assert select[2] == str(tmp_path / "runs" / "seed0" / "cond10")
    (stab, _) = [c for c in calls if c[1:3] == ["neuraldem.bench", "fb_stability"]]
    folder = "cond10+rollout_noise-3+advection_correction-1+mirror_alternate-true+sel"
    assert str(tmp_path / "runs" / "seed0" / folder / "selected.ckpt") in stab
    (tmp_path / "bad").mkdir()
    proc, calls = _run(tmp_path / "bad", LONG_VAL="", BASE="cond10+alt")
    assert proc.returncode == 2 and "BASE=cond10+alt" in proc.stderr and calls == []


def test_missing_long_validation_or_unknown_option_runs_nothing(tmp_path: Path):
    proc, calls = _run(tmp_path)
    assert proc.returncode == 2 and "no long validation set" in proc.stderr and calls == []
    assert "data=fb_small_longval" in proc.stderr
    proc, calls = _run(tmp_path, LONG_VAL="", OPTIONS="rollout.rollout_noise=3+stir")
    assert proc.returncode == 2 and "unknown rollout option 'stir'" in proc.stderr and calls == []
    assert "OPTIONS=rollout.rollout_noise=3+stir" in proc.stderr and not (tmp_path / "runs").exists()
    proc, calls = _run(tmp_path, LONG_VAL="", SEEDS="0")  # without the long set: chosen on 3-s validation alone
    assert proc.returncode == 0, proc.stderr
    (select,) = [c for c in calls if c[1] == "neuraldem.scenes.fluidized_bed.surrogate.selection"]
    assert "--long-val" not in select


def test_finished_baselines_are_not_repeated(tmp_path: Path):
    for part in ("baselines", "baselines-val"):
        done = tmp_path / "runs" / part / "baseline_constant" / "evaluation"
        done.mkdir(parents=True)
        (done / "metrics.json").write_text("{}")
    proc, calls = _run(tmp_path, LONG_VAL="", SEEDS="0")
    assert proc.returncode == 0, proc.stderr
    assert not [c for c in calls if c[1] == "neuraldem.scenes.fluidized_bed.analysis.baselines"]


def test_options_are_passed_on_as_typed(tmp_path: Path):
    """Any of the rollout options, in the one spelling; fb_speed gets those that change a step's cost only."""
    options = "rollout.advection_correction=0.5+rollout.rollout_noise=1"
    proc, calls = _run(tmp_path, LONG_VAL="", SEEDS="0", OPTIONS=options)
    assert proc.returncode == 0, proc.stderr
    (select,) = [c for c in calls if c[1] == "neuraldem.scenes.fluidized_bed.surrogate.selection"]
    (speed,) = [c for c in calls if c[1:3] == ["neuraldem.bench", "fb_speed"]]
    assert {"rollout.advection_correction=0.5", "rollout.rollout_noise=1"} <= set(select)
    assert [a for a in speed if a.startswith("rollout.")] == ["rollout.rollout_noise=1"]
    scored = tmp_path / "runs" / "seed0" / "full+advection_correction-0.5+rollout_noise-1+sel" / "selected.ckpt"
    assert any(f"ckpt={scored}" in c for c in calls if c[1] == "neuraldem.evaluate")
