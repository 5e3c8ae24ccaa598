"""The tiny shipped model (built from the tiny real dataset by tests/conftest.py) loaded once for these tests."""

from __future__ import annotations

from pathlib import Path

import pytest

TINY = "hopper_tiny_test"


@pytest.fixture(scope="module")
def tiny_engine(tiny_pretrained: Path):
    from neuraldem import pretrained
    from neuraldem.serve.hopper_engine import HopperEngine

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NEURALDEM_PRETRAINED_DIR", str(tiny_pretrained))
        return HopperEngine(pretrained.load(TINY, "hopper"))


@pytest.fixture
def use_tiny_model(tiny_pretrained: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """`neuraldem predict` and `serve` in this process see the tiny model."""
    monkeypatch.setenv("NEURALDEM_PRETRAINED_DIR", str(tiny_pretrained))
    return tiny_pretrained
