"""scripts/fb_ablation.sh: each variant becomes one training command with the right overrides and run folder
(a model named in the variant included); unknown variants and models stop it before anything runs."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "fb_ablation.sh"


def _run(tmp_path: Path, variants: str, **extra: str) -> tuple[subprocess.CompletedProcess, list[list[str]]]:
    calls = tmp_path / "calls.txt"
    fake = tmp_path / "python"
    fake.write_text(f'#!/bin/sh\necho "$@" >> {calls}\n')  # records every command instead of running it
    fake.chmod(0o755)
    env = {**os.environ, "PYTHON": str(fake), "VARIANTS": variants, "JOBS": "1", **extra}
    proc = subprocess.run(["bash", str(SCRIPT), str(tmp_path / "runs"), "trainer.max_steps=7"], env=env,
                          capture_output=True, text=True, timeout=60, check=False)
    lines = calls.read_text().splitlines() if calls.exists() else []
    return proc, [line.split() for line in lines]


def test_each_variant_is_one_training_command(tmp_path: Path):
    variants = "noise fb_base/full fb_base/grid_only no_flux stochastic no_ema mirror continuity long short"
    proc, calls = _run(tmp_path, variants)
    assert proc.returncode == 0, proc.stderr
    train = [c for c in calls if c[:2] == ["-m", "neuraldem.train"]]
    assert len(train) == 10
    noise, base, grid, no_flux, stochastic, no_ema, mirror, continuity, long, short = train
    assert "model.net.particle_branch=false" in grid and "model.net.particle_branch=false" not in base
    assert "data.datamodule.input_noise=0.01" in noise and "model.stability.unroll=[1.0]" in noise
    assert "rollout.mixing=absolute" in noise and "callbacks.ema=null" in noise  # the one-step options
    assert "rollout.conserve_volume=false" in noise
    assert not any(a.startswith("model=") for a in noise)
    assert f"hydra.run.dir={tmp_path / 'runs' / 'noise'}" in noise and "trainer.max_steps=7" in noise
    assert "model=fb_base" in base and not any(a.startswith(("model.stability", "data.datamodule", "rollout."))
                                               for a in base)
    assert f"hydra.run.dir={tmp_path / 'runs' / 'fb_base' / 'full'}" in base
    assert "data.datamodule.solids_flux=false" in no_flux and "rollout.mixing=absolute" in no_flux
    assert "model.stability.ensemble=2" in stochastic and "model.net.noise_dim=8" in stochastic
    assert "callbacks.ema=null" in no_ema and "data.datamodule.mirror=true" in mirror
    assert "model.stability.flux_consistency=0.2" in continuity and "trainer.max_steps=16000" in long
    assert short[-1] == "trainer.max_steps=7"  # the command line's own value is the last word
    assert "trainer.max_steps=4000" in short
    assert calls[-1][:2] == ["-m", "neuraldem.scenes.fluidized_bed.analysis.table"]  # then the table of all runs
    (tmp_path / "sel").mkdir()  # the options of the noisy checkpoint selection
    proc, calls = _run(tmp_path / "sel", "noise_sel noise_pooled")
    sel, pooled = [c for c in calls if c[:2] == ["-m", "neuraldem.train"]]
    assert "rollout.rollout_noise=3" in sel
    assert not any(a.startswith("callbacks.rollout_validation") for a in sel)
    assert {"rollout.rollout_noise=3", "callbacks.rollout_validation.reference=pooled"} <= set(pooled)
    (tmp_path / "cond").mkdir()
    proc, calls = _run(tmp_path / "cond", "cond10 cond1000")
    cond, old = [c for c in calls if c[:2] == ["-m", "neuraldem.train"]]
    assert "model.net.scalar_coord_scale=10" in cond and "model.net.scalar_coord_scale=1000" in old


def test_val_scores_each_kept_checkpoint_on_the_validation_part(tmp_path: Path):
    proc, calls = _run(tmp_path, "mirror_alt mirror_both", VAL="1")
    assert proc.returncode == 0, proc.stderr
    modules = [c[1] for c in calls]
    assert modules == ["neuraldem.train", "neuraldem.evaluate", "neuraldem.train", "neuraldem.evaluate",
                       "neuraldem.scenes.fluidized_bed.analysis.table", "neuraldem.scenes.fluidized_bed.analysis.table"]
    alt, alt_val, both, both_val = calls[:4]
    assert "rollout.mirror_alternate=true" in alt and "data.datamodule.mirror=true" not in alt
    assert {"data.datamodule.mirror=true", "rollout.mirror_alternate=true"} <= set(both)
    runs = tmp_path / "runs"
    assert f"ckpt={runs / 'mirror_alt' / 'checkpoints' / 'last.ckpt'}" in alt_val and "part=val" in alt_val
    assert f"hydra.run.dir={runs}-val/mirror_both/evaluation" in both_val
    assert calls[-1][2:] == [f"{runs}-val", "--out", f"{runs}-val/table.md"]
    (tmp_path / "plain").mkdir()
    _, plain = _run(tmp_path / "plain", "mirror_alt")  # without VAL: no validation scoring
    assert [c[1] for c in plain] == ["neuraldem.train", "neuraldem.scenes.fluidized_bed.analysis.table"]


def test_unknown_variant_or_model_runs_nothing(tmp_path: Path):
    for variants, message in (("bogus", "unknown variant 'bogus'"), ("fb_nope/base", "unknown model 'fb_nope'"),
                              ("pf", "unknown variant 'pf'")):
        proc, calls = _run(tmp_path, variants)
        assert proc.returncode == 2 and message in proc.stderr and calls == []


def test_alt_variant_scores_the_trained_net_with_alternating_rollouts(tmp_path: Path):
    proc, calls = _run(tmp_path, "full full+rollout.mirror_alternate=true", VAL="1", TEST="0")
    assert proc.returncode == 0, proc.stderr
    assert [c[1] for c in calls] == ["neuraldem.train", "neuraldem.evaluate", "neuraldem.evaluate",
                                     "neuraldem.scenes.fluidized_bed.analysis.table",
                                     "neuraldem.scenes.fluidized_bed.analysis.table"]
    train, val, alt_val = calls[:3]
    runs = tmp_path / "runs"
    assert "evaluate=false" in train  # TEST=0: the test part is left for the chosen variant
    assert "rollout.mirror_alternate=true" not in val
    assert f"ckpt={runs / 'full' / 'checkpoints' / 'last.ckpt'}" in alt_val  # the same net, no second training
    assert "rollout.mirror_alternate=true" in alt_val and "part=val" in alt_val
    assert f"hydra.run.dir={runs}-val/full+mirror_alternate-true/evaluation" in alt_val  # no = in a Hydra value
    assert (runs / "full" / ".trained").exists()


def test_alt_variant_with_test_scores_the_test_part_too(tmp_path: Path):
    (tmp_path / "runs" / "full" / "checkpoints").mkdir(parents=True)
    (tmp_path / "runs" / "full" / "checkpoints" / "last.ckpt").touch()
    (tmp_path / "runs" / "full" / ".trained").touch()
    proc, calls = _run(tmp_path, "full+rollout.mirror_alternate=true")  # full was trained by an earlier sweep
    assert proc.returncode == 0, proc.stderr
    (test_eval,) = [c for c in calls if c[1] == "neuraldem.evaluate"]
    assert "rollout.mirror_alternate=true" in test_eval and "part=val" not in test_eval
    assert f"hydra.run.dir={tmp_path / 'runs' / 'full+mirror_alternate-true' / 'evaluation'}" in test_eval
    assert not any(c[1] == "neuraldem.train" for c in calls)


def test_resumed_sweep_does_not_train_again(tmp_path: Path):
    _run(tmp_path, "full", VAL="1", TEST="0")
    (tmp_path / "calls.txt").unlink()
    proc, calls = _run(tmp_path, "full", VAL="1", TEST="0")  # the fake evaluate wrote no metrics: scored again
    assert proc.returncode == 0, proc.stderr
    assert [c[1] for c in calls][:1] == ["neuraldem.evaluate"] and not any(c[1] == "neuraldem.train" for c in calls)


def test_alt_of_an_untrained_variant_runs_nothing(tmp_path: Path):
    proc, calls = _run(tmp_path, "mirror+rollout.mirror_alternate=true")
    assert proc.returncode == 2 and "scores variant 'mirror'" in proc.stderr and calls == []


def test_rollout_options_combine_after_the_trained_variant(tmp_path: Path):
    variants = ("full full+rollout.rollout_noise=1 full+rollout.mirror_alternate=true+rollout.rollout_noise=0.5 "
                "full+rollout.rollout_noise=3+rollout.advection_correction=1 full+rollout.mixing=absolute")
    proc, calls = _run(tmp_path, variants, VAL="1", TEST="0")
    assert proc.returncode == 0, proc.stderr
    evals = [c for c in calls if c[1] == "neuraldem.evaluate"]
    assert len(evals) == 5 and sum(c[1] == "neuraldem.train" for c in calls) == 1
    plain, noise, both, corr, mixing = evals
    assert {"rollout.rollout_noise=3", "rollout.advection_correction=1"} <= set(corr)  # passed on as typed
    assert not any(a.startswith("rollout.advection") for a in noise)
    assert not any(a.startswith("rollout.") for a in plain)
    assert "rollout.rollout_noise=1" in noise and "rollout.mirror_alternate=true" not in noise
    assert {"rollout.rollout_noise=0.5", "rollout.mirror_alternate=true"} <= set(both)
    assert f"hydra.run.dir={tmp_path / 'runs'}-val/full+mirror_alternate-true+rollout_noise-0.5/evaluation" in both
    assert "rollout.mixing=absolute" in mixing  # any of the six options
    for i, bad in enumerate(("stir", "noise3", "rollout.stir=1", "rollout.rollout_noise=")):
        (tmp_path / f"bad{i}").mkdir()
        proc, calls = _run(tmp_path / f"bad{i}", f"full full+{bad}")
        assert proc.returncode == 2 and f"unknown rollout option '{bad}'" in proc.stderr and calls == []


def test_sel_chooses_the_checkpoint_under_the_rollout_options_then_scores_it(tmp_path: Path):
    longval = str(tmp_path / "fb_small_longval")
    options = "rollout.rollout_noise=3+rollout.advection_correction=1+rollout.mirror_alternate=true"
    proc, calls = _run(tmp_path, f"full full+{options}+sel", VAL="1", SELECT_FROM="4500", LONG_VAL=longval)
    assert proc.returncode == 0, proc.stderr
    assert [c[1] for c in calls] == ["neuraldem.train", "neuraldem.evaluate",
                                     "neuraldem.scenes.fluidized_bed.surrogate.selection", "neuraldem.evaluate",
                                     "neuraldem.evaluate",
                                     "neuraldem.scenes.fluidized_bed.analysis.table",
                                     "neuraldem.scenes.fluidized_bed.analysis.table"]
    runs = tmp_path / "runs"
    chosen = runs / "full+rollout_noise-3+advection_correction-1+mirror_alternate-true+sel" / "selected.ckpt"
    select = calls[2]
    assert select[2] == str(runs / "full")
    flags = " ".join(select[3:])
    assert "rollout.rollout_noise=3 rollout.advection_correction=1 rollout.mirror_alternate=true" in flags
    assert "--from-step 4500" in flags and "--seeds 0 1" in flags and f"--long-val {longval}" in flags
    assert f"--copy-to {chosen}" in flags
    test_eval, val_eval = calls[3:5]  # the chosen checkpoint, not last.ckpt, with the same rollout options
    for c in (test_eval, val_eval):
        assert f"ckpt={chosen}" in c
        assert {"rollout.rollout_noise=3", "rollout.advection_correction=1", "rollout.mirror_alternate=true"} <= set(c)
    assert "part=val" in val_eval and "part=val" not in test_eval
    (tmp_path / "plain").mkdir()  # without LONG_VAL: no --long-val
    _, calls = _run(tmp_path / "plain", "full full+sel")
    (select,) = [c for c in calls if c[1] == "neuraldem.scenes.fluidized_bed.surrogate.selection"]
    assert "--long-val" not in select and not any(a.startswith("rollout.") for a in select) and "--from-step" in select


def test_a_killed_training_goes_on_from_its_latest_state(tmp_path: Path):
    """A run folder with checkpoints/latest.ckpt and no .trained mark resumes (ckpt_path=..., folder kept); one
    without a checkpoint starts afresh in an emptied folder."""
    killed = tmp_path / "runs" / "full"
    (killed / "checkpoints").mkdir(parents=True)
    (killed / "checkpoints" / "latest.ckpt").write_text("state")
    fresh = tmp_path / "runs" / "no_ema"
    fresh.mkdir(parents=True)
    (fresh / "stale.txt").write_text("half a run without a checkpoint")
    proc, calls = _run(tmp_path, "full no_ema", TEST="0")
    assert proc.returncode == 0, proc.stderr
    full, no_ema = [c for c in calls if c[:2] == ["-m", "neuraldem.train"]]
    assert full[-1] == f"ckpt_path={killed / 'checkpoints' / 'latest.ckpt'}"
    assert (killed / "checkpoints" / "latest.ckpt").exists()
    assert not any(a.startswith("ckpt_path=") for a in no_ema) and not (fresh / "stale.txt").exists()


def test_the_script_knows_the_rollout_options_of_every_command():
    """fb_ablation.sh checks a variant's rollout options against a list of their names before anything runs: the
    list is RolloutOptions' fields."""
    from neuraldem.scenes.fluidized_bed.surrogate.options import OPTION_NAMES

    line = next(x for x in SCRIPT.read_text().splitlines() if x.startswith("ROLLOUT_KEYS="))
    assert line.split("=", 1)[1].strip('"').split() == list(OPTION_NAMES)


def test_check_only_runs_nothing(tmp_path: Path):
    proc, calls = _run(tmp_path, "full full+rollout.rollout_noise=3+sel", CHECK="1")
    assert proc.returncode == 0 and calls == [] and not (tmp_path / "runs").exists(), proc.stderr
