"""Pages and bad input at start: a missing or damaged model file stops `neuraldem serve` with the one-line
DataError (file and rebuild command), a scene without a shipped model leaves its page off, an unknown page is
refused."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from neuraldem.errors import ConfigError
from tests.conftest import TINY


@pytest.fixture
def model_copy(tiny_pretrained: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A copy of the tiny shipped-model folder that `neuraldem serve` loads (to break on purpose)."""
    shutil.copytree(tiny_pretrained / TINY, tmp_path / TINY)
    monkeypatch.setenv("NEURALDEM_MODELS", str(tmp_path))
    return tmp_path / TINY


def serve_error(capsys, *args: str) -> str:
    from neuraldem.serve.__main__ import main

    with pytest.raises(SystemExit) as stop:
        main(["port=0", *args])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err


def test_a_missing_model_file_is_one_line_with_the_rebuild_command(model_copy: Path, capsys):
    (model_copy / "field.onnx").unlink()  # what the page answers with
    err = serve_error(capsys)
    assert f"shipped model file {model_copy / 'field.onnx'} is missing: rebuild it:" in err
    assert "neuraldem train" in err and "&& neuraldem release ckpt=<that run>/checkpoints/" in err


def test_a_damaged_model_file_is_one_line(model_copy: Path, capsys):
    gp = model_copy / "gp.npz"
    gp.write_bytes(gp.read_bytes()[:-8] + b"damaged!")
    err = serve_error(capsys)
    assert f"shipped model file {gp} is damaged" in err


def test_without_a_shipped_model_no_page_is_served(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys):
    from neuraldem import pretrained

    monkeypatch.setenv("NEURALDEM_MODELS", str(tmp_path))  # your folders: none of yours ...
    monkeypatch.setattr(pretrained, "shipped_dir", lambda: tmp_path / "shipped")  # ... and none shipped
    err = serve_error(capsys)
    assert "no page can be served: hopper: page off: no pretrained hopper model is shipped" in err
    assert "bed: page off: no pretrained fluidized_bed model is shipped" in err and err.endswith("model=NAME\n")


def scene_pages() -> dict[str, tuple[str, str]]:
    """The pages `neuraldem serve` hands the server: {route: (scene kind, page module)} of the scene registry."""
    from neuraldem.scenes import registry

    return {s.route: (s.kind, s.page) for s in registry().values() if s.page}


def test_an_unknown_page_is_refused(capsys):
    from neuraldem.serve.app import prepare_pages

    with pytest.raises(ConfigError, match="unknown page 'silo': choose from hopper, bed"):
        prepare_pages(scene_pages(), None, None, 0.05, ["silo"])
    err = serve_error(capsys, "page=silo")  # through the command: one line
    assert "unknown page 'silo': choose from hopper, bed" in err


def test_every_page_module_has_what_the_server_calls():
    import importlib

    pages = scene_pages()
    assert set(pages) == {"hopper", "bed"}
    for route, (kind, name) in pages.items():
        module = importlib.import_module(name)
        assert kind == module.SCENE_KIND and isinstance(module.TITLE, str), route
        assert callable(module.prepare) and callable(module.page), route
