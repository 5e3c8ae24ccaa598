"""Where models are found: your folders (`NEURALDEM_MODELS`, default <data dir>/models; the old
`NEURALDEM_PRETRAINED_DIR` read for one release with a note) before the shipped ones, which stay available;
`model=` takes a released model's folder; `release` writes into your folder by default."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from neuraldem import pretrained
from neuraldem.errors import ConfigError
from tests.conftest import TINY
from tests.helpers import run_module


@pytest.fixture
def clean_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("NEURALDEM_MODELS", raising=False)
    monkeypatch.delenv("NEURALDEM_PRETRAINED_DIR", raising=False)


def test_your_folders_add_to_the_shipped_models(tiny_pretrained: Path, clean_env, monkeypatch, tmp_path: Path):
    monkeypatch.setenv("NEURALDEM_DATA", str(tmp_path))
    assert pretrained.user_dirs() == [tmp_path / "models"] and pretrained.release_dir() == tmp_path / "models"
    assert TINY not in pretrained.names() and pretrained.default_for("hopper") == "hopper_small"
    monkeypatch.setenv("NEURALDEM_MODELS", f"{tmp_path / 'none'}:{tiny_pretrained}")
    assert pretrained.names()[0] == TINY and {"hopper_small", "fb_small"} <= set(pretrained.names())
    assert pretrained.default_for("hopper") == TINY  # yours first
    assert pretrained.default_for("fluidized_bed") == "fb_small"  # the shipped one where you have none
    assert pretrained.load("hopper_small", "hopper").folder == pretrained.shipped_dir() / "hopper_small"


def test_a_name_of_yours_wins_over_a_shipped_one(clean_env, monkeypatch, tmp_path: Path):
    shutil.copytree(pretrained.shipped_dir() / "hopper_small", tmp_path / "hopper_small")
    monkeypatch.setenv("NEURALDEM_MODELS", str(tmp_path))
    assert pretrained.load("hopper_small").folder == tmp_path / "hopper_small"


def test_the_old_variable_still_works_with_a_note(tiny_pretrained: Path, clean_env, monkeypatch, capsys):
    monkeypatch.setattr(pretrained, "_noted", [])
    monkeypatch.setenv("NEURALDEM_PRETRAINED_DIR", str(tiny_pretrained))
    assert TINY in pretrained.names() and "hopper_small" in pretrained.names()
    pretrained.names()
    err = capsys.readouterr().err
    assert err.count("NEURALDEM_PRETRAINED_DIR is the old name of NEURALDEM_MODELS") == 1, err


def test_model_takes_a_released_folder(tiny_pretrained: Path, clean_env, tmp_path: Path):
    folder = tiny_pretrained / TINY
    assert pretrained.load(str(folder), "hopper").name == TINY
    proc = run_module("neuraldem", "predict", "hopper", f"model={folder}", "alpha=40", "mu_s=0.3", "mu_r=0.1",
                      "fields=false", f"out={tmp_path / 'p'}")
    assert proc.returncode == 0, proc.stderr
    assert f"(model {TINY})" in proc.stdout
    assert json.loads((tmp_path / "p" / "answer.json").read_text())["model"] == TINY
    scan = run_module("neuraldem", "scan", "hopper", f"model={folder}", "alpha=20:50:3", "mu_s=0.2:0.6:2", "mu_r=0.1",
                      f"out={tmp_path / 's'}")
    assert scan.returncode == 0 and (tmp_path / "s" / "scan.json").is_file(), scan.stderr


@pytest.mark.parametrize(("model", "expected"), [
    ("{tiny}", "is not a released model (no meta.json): it holds the models hopper_tiny_test: pass model="),
    ("{tmp}", "is not a released model (no meta.json): release a checkpoint into it first: neuraldem release"),
    ("{shipped}/fb_small", "is a fluidized_bed model, not a hopper one"),
])
def test_a_folder_that_is_not_a_model_is_one_line(model: str, expected: str, tiny_pretrained: Path, tmp_path: Path):
    value = model.format(tiny=tiny_pretrained, tmp=tmp_path, shipped=pretrained.shipped_dir())
    with pytest.raises(ConfigError, match=None) as err:
        pretrained.load(value, "hopper")
    assert f"model={value}" in str(err.value) and expected in str(err.value)
    proc = run_module("neuraldem", "predict", "hopper", f"model={value}", "alpha=40", "mu_s=0.3", "mu_r=0.1")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and expected in proc.stderr, proc.stderr


def test_serve_shows_a_released_folder(tiny_pretrained: Path, clean_env, monkeypatch):
    from neuraldem.serve.app import model_for

    assert model_for("hopper", str(tiny_pretrained / TINY)) == (str(tiny_pretrained / TINY), "")
    assert model_for("fluidized_bed", str(tiny_pretrained / TINY)) == ("fb_small", "")


def test_release_writes_into_your_folder_by_default(clean_env, monkeypatch, tmp_path: Path, capsys):
    from neuraldem.release import main

    monkeypatch.setenv("NEURALDEM_DATA", str(tmp_path))
    with pytest.raises(SystemExit):
        main(["--help"])
    text = "".join(capsys.readouterr().out.split())  # argparse wraps a long path at its dashes
    assert f"now{tmp_path / 'models'}" in text and "out=src/neuraldem/pretrained" in text


def test_a_release_records_the_asked_range_beside_the_covered_one(tiny_pretrained: Path, fb_tiny_pretrained: Path,
                                                                   tmp_path: Path):
    from neuraldem.scenes.parameters import ranges_line

    meta = json.loads((tiny_pretrained / TINY / "meta.json").read_text())
    assert meta["asked_range"] == {"alpha": [0.0, 60.0], "mu_s": [0.05, 1.0], "mu_r": [0.0, 0.5]}
    lo, hi = meta["trained_range"]["alpha"]
    assert 0 < lo < hi < 60 and f"alpha {lo:.4g} .. {hi:.4g} (asked 0 .. 60)" in ranges_line(meta)
    bed = json.loads((fb_tiny_pretrained / "fb_tiny_test" / "meta.json").read_text())
    assert bed["asked_range"] == {"inlet_velocity": [1.2, 2.2]}
    proc = run_module("neuraldem", "predict", "hopper", f"model={tiny_pretrained / TINY}", "alpha=62", "mu_s=0.3",
                      "mu_r=0.1", "fields=false", f"out={tmp_path}")
    assert proc.returncode == 0, proc.stderr
    assert (f"warning: GP: alpha=62 is outside the trained range {lo:.4g} .. {hi:.4g}; datagen was asked for 0 .. 60, "
            "the runs cover less (more runs fill it): an extrapolation") in proc.stderr
