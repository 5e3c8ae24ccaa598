"""A scene is a plug-in: a toy scene in one folder outside the package (tests/plugins/toy_drum, whose "solver" is a
labelled synthetic stand-in) registers with NEURALDEM_SCENES, and the generic commands reach it: datagen composes
its data config and runs its pipeline, predict answers with its what-if, the explorer prepares its page, report
lists its table."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.pretrained.card import write_card
from tests.helpers import run_module

PLUGIN = Path(__file__).resolve().parents[1] / "plugins" / "toy_drum"


@pytest.fixture
def toy_scene(monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("NEURALDEM_SCENES", str(PLUGIN))
    return PLUGIN


@pytest.fixture
def toy_model(tmp_path: Path) -> Path:
    """A released-model folder of the toy scene (what `predict` reads its inputs from)."""
    folder = tmp_path / "models" / "toy_model"
    folder.mkdir(parents=True)
    (folder / "meta.json").write_text(json.dumps({"name": "toy_model", "kind": "toy_drum",
                                                  "inputs": ["speed", "friction"], "files": {}}))
    write_card(folder)
    return folder.parent


def test_the_plugin_registers_beside_the_built_in_scenes(toy_scene: Path):
    from neuraldem.scenes import by_name, kinds, scene

    assert kinds()[:3] == ["hopper", "hopper_refill", "fluidized_bed"] and "toy_drum" in kinds()
    drum = scene("toy_drum")
    assert by_name("drum") is drum and drum.parameters.names == ["speed", "friction"]
    assert drum.config_dir == PLUGIN / "conf"


def test_datagen_composes_the_plugins_config_and_runs_its_pipeline(toy_scene: Path, tmp_path: Path):
    env = {"NEURALDEM_SCENES": str(PLUGIN), "NEURALDEM_DATA": str(tmp_path)}
    proc = run_module("neuraldem", "datagen", "data=toy_drum_tiny", "progress=false",
                      f"hydra.run.dir={tmp_path / 'run'}", env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    manifest = json.loads((tmp_path / "datasets" / "toy_drum_tiny" / "manifest.json").read_text())
    assert manifest["kind"] == "toy_drum" and "synthetic stand-in" in manifest["solver"]["name"]
    assert sum(r["status"] == "ok" for r in manifest["simulations"]) == 6
    report = run_module("neuraldem", "report", "drum-table", f"dataset={tmp_path / 'datasets' / 'toy_drum_tiny'}",
                        env=env)
    assert report.returncode == 0 and report.stdout.count("repose=") == 6, report.stderr


def test_predict_dispatches_to_the_plugins_what_if(toy_scene: Path, toy_model: Path, tmp_path: Path):
    env = {"NEURALDEM_SCENES": str(PLUGIN), "NEURALDEM_PRETRAINED_DIR": str(toy_model)}
    proc = run_module("neuraldem", "predict", "drum", "speed=10", "friction=0.5", f"out={tmp_path}", env=env)
    assert proc.returncode == 0, proc.stderr
    assert "| dynamic angle of repose [deg] | 33.05 |" in proc.stdout
    twice = run_module("neuraldem", "predict", "drum", "speed=10", "speed=12", "friction=0.5", env=env)
    assert twice.returncode == 2 and "speed= is given twice" in twice.stderr
    beyond = run_module("neuraldem", "predict", "drum", "speed=100", "friction=0.5", env=env)
    assert beyond.returncode == 2 and "speed=100 is outside what the solver can run (0 .. 60)" in beyond.stderr


def test_the_explorer_serves_the_plugins_page(toy_scene: Path, toy_model: Path, monkeypatch: pytest.MonkeyPatch):
    from neuraldem.scenes import registry
    from neuraldem.serve.app import prepare_pages

    monkeypatch.setenv("NEURALDEM_PRETRAINED_DIR", str(toy_model))
    routes = {s.route: (s.kind, s.page) for s in registry().values() if s.page}
    assert routes["drum"] == ("toy_drum", "toy_drum.page")
    pages, notes = prepare_pages(routes, None, None, 0.05, ["drum"])
    assert [p.route for p in pages] == ["drum"] and pages[0].shared["model"] == "toy_model" and not notes
    html = pages[0].module.page(pages[0].shared).object
    assert "33.05 deg (toy_model)" in html


def test_a_folder_that_is_not_a_scene_is_refused_in_one_line(tmp_path: Path):
    proc = run_module("neuraldem", "predict", "hopper", "--help", env={"NEURALDEM_SCENES": str(tmp_path)})
    assert proc.returncode == 2 and "is not a scene package (no __init__.py)" in proc.stderr
    assert "Traceback" not in proc.stderr
