"""Scene files of your own (`neuraldem scene new|list|show`) in the user config folder that every Hydra command
searches: the file written composes to the scene it started from, names are never shadowed, and a missing scene,
a doubled one or a bad key of a scene file is one line naming the folders or the file."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from neuraldem.errors import ConfigError
from tests.helpers import run_module


@pytest.fixture
def config_home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("NEURALDEM_CONFIG", str(tmp_path / "cfg"))
    return tmp_path / "cfg"


def scene_cmd(capsys, *argv: str) -> str:
    from neuraldem.scene_files import main

    assert main(list(argv)) == 0
    return capsys.readouterr().out


def without_name(cfg: dict) -> dict:
    """A composed data config without what its name decides (its name and dataset folder)."""
    out = {k: v for k, v in cfg.items() if k not in ("name", "dataset_dir")}
    out["datamodule"] = {k: v for k, v in out["datamodule"].items() if k not in ("name", "dataset_dir")}
    return out


@pytest.mark.parametrize("source", ["hopper_small", "fb_small", "hopper_tiny"])
def test_a_new_scene_is_every_key_commented_and_composes_to_its_source(source: str, config_home: Path, capsys):
    from neuraldem.scene_files import composed

    out = scene_cmd(capsys, "new", "mine", f"from={source}")
    path = config_home / "data" / "mine.yaml"
    assert f"wrote {path}" in out and "neuraldem datagen data=mine" in out
    text = path.read_text()
    assert text.startswith("# mine: your own") and f"  - {source}\n" in text and "docs/your-own-scene.md" in text
    assert "# [m] particle diameter" in text or "# [m] box width" in text
    assert max(len(line) for line in text.splitlines()) <= 120
    assert without_name(composed("mine")) == without_name(composed(source))
    assert yaml.safe_load(text)["name"] == "mine"


def test_list_and_show_name_yours_beside_the_packaged_scenes(config_home: Path, capsys):
    scene_cmd(capsys, "new", "name=mine", "from=hopper_tiny")  # the name as key=value works too
    listed = scene_cmd(capsys, "list")
    assert f"| mine | hopper | yours | {config_home / 'data' / 'mine.yaml'} |" in listed
    assert "| fb_small | fluidized_bed | packaged |" in listed and "gns_export" not in listed
    shown = scene_cmd(capsys, "show", "mine")
    assert shown.startswith(f"# mine: yours, {config_home / 'data' / 'mine.yaml'} (inherits hopper_tiny <- "
                            "hopper_small)")
    assert "n_particles: 500" in shown and "kind: hopper" in shown


@pytest.mark.parametrize(("argv", "expected"), [
    (["new", "hopper_small", "from=hopper_small"], "hopper_small is a packaged scene"),
    (["new", "my hopper", "from=hopper_small"], "scene name 'my hopper' is invalid"),
    (["new", "mine", "from=nope"], "no scene 'nope': the scenes are"),
    (["new", "mine"], "the following arguments are required: from="),
    (["show", "nope"], "no scene 'nope'"),
    (["frobnicate"], "unknown action 'frobnicate': choose one of new, list, show"),
])
def test_bad_scene_commands_are_one_line(argv: list[str], expected: str, config_home: Path, capsys):
    from neuraldem.scene_files import main

    with pytest.raises(SystemExit) as stop:
        main(argv)
    err = capsys.readouterr().err
    assert stop.value.code == 2 and expected in err and err.count("\n") == 1, err


def test_an_existing_file_is_kept_unless_forced(config_home: Path, capsys):
    from neuraldem.scene_files import main

    scene_cmd(capsys, "new", "mine", "from=hopper_tiny")
    with pytest.raises(SystemExit):
        main(["new", "mine", "from=fb_tiny"])
    assert "mine.yaml exists: edit it, or write it again with force=true" in capsys.readouterr().err
    scene_cmd(capsys, "new", "mine", "from=fb_tiny", "force=true")
    assert "  - fb_tiny\n" in (config_home / "data" / "mine.yaml").read_text()


def test_a_missing_or_doubled_config_is_refused_before_hydra_composes(config_home: Path, capsys):
    from neuraldem.cli import check_overrides
    from neuraldem.config.user import config_file

    with pytest.raises(SystemExit):
        check_overrides("datagen", ["data=nope"])
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "neuraldem datagen: no data config 'nope': searched " in err
    assert str(config_home / "data") in err and "neuraldem scene new nope from=hopper_small" in err
    (config_home / "data").mkdir(parents=True)
    (config_home / "data" / "hopper_tiny.yaml").write_text("name: hopper_tiny\n")  # written by hand
    with pytest.raises(ConfigError, match=r"data=hopper_tiny is found twice: .*conf/data/hopper_tiny.yaml \(packaged\) "
                                          r"and .*cfg/data/hopper_tiny.yaml \(yours\); the first would silently win"):
        config_file("data", "hopper_tiny")
    with pytest.raises(SystemExit):
        check_overrides("train", ["experiment=hopper_micro", "data=hopper_tiny"])
    assert "found twice" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        check_overrides("train", ["experiment=nope"])
    err = capsys.readouterr().err
    assert "no experiment config 'nope': searched" in err and "choose one of fb, fb_quick" in err


def test_every_hydra_command_composes_your_scene_and_names_its_file_on_a_bad_key(tmp_path: Path):
    cfg = tmp_path / "cfg"
    env = {"NEURALDEM_CONFIG": str(cfg), "NEURALDEM_DATA": str(tmp_path / "data")}
    assert run_module("neuraldem", "scene", "new", "mine", "from=hopper_tiny", env=env).returncode == 0
    job = run_module("neuraldem", "train", "experiment=hopper_micro", "data=mine", "--cfg", "job", env=env)
    assert job.returncode == 0 and "name: mine" in job.stdout, job.stderr
    path = cfg / "data" / "mine.yaml"
    path.write_text(path.read_text().replace("insertion_fraction:", "insertion_fractoin:"))
    proc = run_module("neuraldem", "datagen", "data=mine", f"hydra.run.dir={tmp_path / 'run'}", env=env)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert f"neuraldem: error: scene file {path}: unknown key(s) ['insertion_fractoin'] in data.scene" in proc.stderr
    assert "correct it in that file" in proc.stderr and not (tmp_path / "data" / "datasets" / "mine").exists()


@pytest.mark.parametrize(("source", "section", "line"), [
    ("hopper_tiny", "data.storage", "storage:\n  keep_rwa: true\n"),
    ("hopper_tiny", "data.parameters", "parameters:\n  sed: 3\n"),
    ("hopper_tiny", "data.characterization", "characterization:\n  enable: false\n"),
    ("fb_tiny", "data.parameters", "parameters:\n  packings: 2\n"),
    ("fb_tiny", "data.parameters.long", "parameters:\n  long:\n    parts: val\n"),
    ("fb_tiny", "data.storage", "storage:\n  keep_rwa: true\n"),
])
def test_a_typo_outside_the_scene_section_is_refused_naming_the_file(source: str, section: str, line: str,
                                                                     tmp_path: Path):
    """Every section datagen reads checks its keys: a misspelt key is one line naming the file, not ignored."""
    cfg = tmp_path / "cfg"
    env = {"NEURALDEM_CONFIG": str(cfg), "NEURALDEM_DATA": str(tmp_path / "data")}
    path = cfg / "data" / "mine.yaml"
    path.parent.mkdir(parents=True)
    path.write_text(f"defaults:\n  - {source}\n  - _self_\nname: mine\n{line}")
    proc = run_module("neuraldem", "datagen", "data=mine", f"hydra.run.dir={tmp_path / 'run'}", env=env)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert f"neuraldem: error: scene file {path}: unknown key(s)" in proc.stderr and f" in {section};" in proc.stderr
    assert not (tmp_path / "data" / "datasets" / "mine").exists()
