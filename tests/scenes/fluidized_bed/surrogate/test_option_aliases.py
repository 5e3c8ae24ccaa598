"""The old spellings of the bed's rollout options still work for one release (each prints the new one and does
the same), and appear nowhere in the code, configs and scripts but the one alias module. The only test file that
spells them."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from neuraldem.cli import CommandParser, renamed_overrides
from neuraldem.scenes.fluidized_bed.surrogate.options import (
    OPTION_NAMES,
    BedStability,
    RolloutOptions,
    add_arguments,
    training_stability,
)
from neuraldem.scenes.fluidized_bed.surrogate.rollout_run import RolloutFile
from tests.helpers import REPO, run_module

OLD_SPELLINGS = ("conserve_solid_volume", "--rollout-noise", "--mirror-alternate", "--advection-correction",
                 "fluidized_bed.rollout_noise", "fluidized_bed.mirror_alternate", "fluidized_bed.advection_correction",
                 "fluidized_bed.advection_flux", "fluidized_bed.mixing", "model.stability.rollout_noise",
                 "model.stability.mirror_alternate", "model.stability.advection_correction",
                 "model.stability.advection_flux", "model.stability.conserve_volume", "model.stability.mixing")
ALIAS_MODULE = "src/neuraldem/scenes/fluidized_bed/surrogate/option_aliases.py"


def test_old_spellings_live_in_the_alias_module_only():
    found = subprocess.run(["git", "grep", "-n", "-F", *[f"-e{s}" for s in OLD_SPELLINGS], "--", "src", "conf",
                            "scripts", f":(exclude){ALIAS_MODULE}"], cwd=REPO, capture_output=True, text=True,
                           check=False)
    assert found.returncode == 1 and found.stdout == "", found.stdout  # 1: nothing found
    alias = (REPO / ALIAS_MODULE).read_text()
    assert all(s in alias for s in OLD_SPELLINGS)


@pytest.mark.parametrize(("command", "old", "new"), [
    ("train", "model.stability.rollout_noise=3", "rollout.rollout_noise=3"),
    ("train", "+model.stability.mixing=advect", "rollout.mixing=advect"),
    ("evaluate", "fluidized_bed.conserve_solid_volume=true", "rollout.conserve_volume=true"),
    ("evaluate", "fluidized_bed.advection_flux=consistent", "rollout.advection_flux=consistent"),
    ("rollout", "conserve_solid_volume=false", "rollout.conserve_volume=false"),
    ("rollout", "mirror_alternate=true", "rollout.mirror_alternate=true"),
])
def test_an_old_hydra_key_is_read_as_the_new_one_with_a_note(command: str, old: str, new: str, capsys):
    assert renamed_overrides(command, ["seed=1", old]) == ["seed=1", new]
    err = capsys.readouterr().err
    assert f"{old.lstrip('+').split('=')[0]}= is the old spelling" in err and new in err
    assert renamed_overrides("evaluate", ["rollout.rollout_noise=3"]) == ["rollout.rollout_noise=3"]  # no note
    assert capsys.readouterr().err == ""


def test_an_old_training_key_composes_the_same_model(compose_train_cfg):
    """`model.stability.<option>` on the command line is `rollout.<option>`: the same composed config."""
    from neuraldem.train import model_kwargs

    new = compose_train_cfg("experiment=fb", "rollout.rollout_noise=3", "rollout.mixing=absolute")
    old = compose_train_cfg("experiment=fb", *renamed_overrides("train", ["model.stability.rollout_noise=3",
                                                                          "model.stability.mixing=absolute"]))
    assert model_kwargs(old) == model_kwargs(new) and model_kwargs(new)["stability"]["rollout_noise"] == 3


def test_an_old_training_key_in_a_config_file_still_counts(capsys):
    """A config file of one's own that still sets a rollout option under model.stability: read as rollout.*, with
    a note; the rollout group wins where it sets the option too."""
    stability = {"unroll": [1.0], "mixing": "advect", "conserve_volume": True, "rollout_noise": 2.0}
    merged = training_stability(stability, {"rollout_noise": 3.0, "mixing": None})
    assert merged == training_stability({"unroll": [1.0]}, {"mixing": "advect", "conserve_volume": True,
                                                            "rollout_noise": 3.0})
    err = capsys.readouterr().err
    assert "model.stability.mixing in a config is the old spelling (kept for one release): write rollout.mixing" in err
    assert "rollout.rollout_noise (its value 3.0 is used, not 2.0)" in err
    assert BedStability.from_config(merged).mixing == "advect"


def test_the_tools_old_flags_give_the_same_options_and_print_the_new_form(capsys):
    p = CommandParser(prog="tool")
    add_arguments(p)
    old = RolloutOptions.from_args(p.parse_args(["--rollout-noise", "3", "--advection-correction", "1",
                                                 "--mirror-alternate"]))
    note = capsys.readouterr().err
    assert old == RolloutOptions(rollout_noise=3.0, advection_correction=1.0, mirror_alternate=True)
    assert "rollout.rollout_noise=3 rollout.advection_correction=1 rollout.mirror_alternate=true" in note
    new = RolloutOptions.from_args(p.parse_args(old.overrides()))
    assert new == old and capsys.readouterr().err == ""
    assert "--rollout-noise" not in p.format_help() and "rollout.rollout_noise=" in p.format_help()
    assert list(p.options()) == [f"rollout.{n}" for n in OPTION_NAMES]  # the keys: the six, no old flag


@pytest.mark.solver
def test_an_old_rollout_key_rolls_out_the_same(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path, tmp_path: Path):
    """`evaluate rollout conserve_solid_volume=true` (old) and `rollout.conserve_volume=true`: the same rollout."""
    env = {"NEURALDEM_DATA": str(fb_tiny_dataset.parent.parent)}
    runs = {}
    for name, key in (("old", "conserve_solid_volume=true"), ("new", "rollout.conserve_volume=true")):
        proc = run_module("neuraldem.rollout", f"ckpt={fb_tiny_checkpoint}", "velocity=1.228531", "steps=3",
                          key, "vtk=false", "progress=false", f"hydra.run.dir={tmp_path / name}", env=env)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        runs[name] = json.loads((tmp_path / name / "rollout.json").read_text())
        assert ("old spelling" in proc.stderr) == (name == "old")
    assert runs["old"]["conserve_solid_volume"] and runs["old"]["message"] == runs["new"]["message"]
    with RolloutFile(tmp_path / "old" / "rollout.h5") as a, RolloutFile(tmp_path / "new" / "rollout.h5") as b:
        np.testing.assert_array_equal(a.grid_field("solid_fraction"), b.grid_field("solid_fraction"))
        np.testing.assert_array_equal(a.grid_field("mixing"), b.grid_field("mixing"))


@pytest.mark.solver
def test_the_old_flags_of_a_bench_give_the_same_map(fb_tiny_flux_checkpoint: Path, fb_tiny_dataset: Path,
                                                     tmp_path: Path):
    """`bench fb_stability --ckpt C ... --advection-correction 1 --mirror-alternate` (as scripts/compare_commits.sh
    and older scripts type it) maps what `ckpt=C ... rollout.advection_correction=1 rollout.mirror_alternate=true`
    maps."""
    from neuraldem.bench.__main__ import main as bench_main

    common = ["--velocities", "1.228531", "1.3", "--steps", "2", "--dataset", str(fb_tiny_dataset)]
    assert bench_main(["fb_stability", "--ckpt", str(fb_tiny_flux_checkpoint), *common, "--advection-correction", "1",
                       "--mirror-alternate", "--out", str(tmp_path / "old.json")]) == 0
    assert bench_main(["fb_stability", "--ckpt", str(fb_tiny_flux_checkpoint), *common,
                       "rollout.advection_correction=1", "rollout.mirror_alternate=true",
                       "--out", str(tmp_path / "new.json")]) == 0
    old, new = (json.loads((tmp_path / f"{n}.json").read_text())["results"] for n in ("old", "new"))
    assert old["advection_correction"] == new["advection_correction"] == 1.0 and old["mirror_alternate"] is True
    assert old["series"][0]["points"] == new["series"][0]["points"]
