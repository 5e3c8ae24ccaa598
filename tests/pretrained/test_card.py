"""Model cards: every shipped model has one that describes its meta.json; a card that is missing or describes
another meta.json is refused by the loader in one line naming the file and the command that writes it again."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from neuraldem import pretrained
from neuraldem.errors import DataError
from neuraldem.pretrained.card import CARD, check_card, write_card


@pytest.mark.parametrize("name", ["hopper_small", "fb_small"])
def test_each_shipped_model_has_a_card_of_its_meta(name: str):
    model = pretrained.load(name)
    card = (model.folder / CARD).read_text()
    assert card.startswith(f"# Model card: {name}") and "## Test scores" in card and "## Known weak regions" in card
    assert "GP on the scene parameters" in card and "training mean" in card


def test_a_missing_or_stale_card_is_refused_naming_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    shutil.copytree(Path(pretrained.__file__).parent / "hopper_small", tmp_path / "hopper_small")
    monkeypatch.setenv("NEURALDEM_PRETRAINED_DIR", str(tmp_path))
    folder = tmp_path / "hopper_small"
    meta = folder / "meta.json"
    meta.write_text(meta.read_text().replace('"hopper_small"', '"hopper_small"', 1) + "\n")  # another meta.json
    with pytest.raises(DataError, match=rf"{CARD} does not describe .*meta.json .*card_only=true"):
        pretrained.load("hopper_small")
    write_card(folder)
    assert pretrained.load("hopper_small").name == "hopper_small"
    (folder / CARD).unlink()
    with pytest.raises(DataError, match=rf"{CARD} is missing"):
        check_card(folder, "neuraldem release ...")
