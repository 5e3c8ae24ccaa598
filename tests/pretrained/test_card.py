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


def test_a_second_read_of_the_test_runs_is_recorded_and_a_changed_recipe_refused(tmp_path: Path):
    """The release records each read of a dataset's test runs; a second release of the same recipe is recorded
    as such, one of a changed recipe of the same family is refused in one line unless reuse_test (then the card
    says so)."""
    import json

    from neuraldem.errors import ConfigError
    from neuraldem.pretrained.building import TEST_READS, read_test_split
    from neuraldem.pretrained.card import render

    def run(overrides: list[str]) -> Path:
        ckpt = tmp_path / "-".join(overrides).replace("=", "_") / "checkpoints" / "last.ckpt"
        (ckpt.parent.parent / ".hydra").mkdir(parents=True)
        (ckpt.parent.parent / ".hydra" / "overrides.yaml").write_text(json.dumps(overrides))  # YAML reads JSON
        return ckpt

    dataset = tmp_path / "data"
    dataset.mkdir()
    first = read_test_split(dataset, run(["experiment=fb", "seed=0"]), "a")
    again = read_test_split(dataset, run(["experiment=fb", "seed=1", "trainer=cpu"]), "b")  # same recipe
    assert len(first) == 1 and len(again) == 2 and not again[-1]["changed_recipe"]
    changed = run(["experiment=fb", "model.net.scalar_coord_scale=10"])
    with pytest.raises(ConfigError, match="a changed recipe needs new test runs.*reuse_test=true"):
        read_test_split(dataset, changed, "c")
    reads = read_test_split(dataset, changed, "c", reuse=True)
    assert reads[-1]["changed_recipe"] and len(json.loads((dataset / TEST_READS).read_text())) == 3
    card = render({"name": "c", "kind": "fluidized_bed", "test_reads": reads, "test_errors": {"n_test_runs": 3}},
                  "0" * 64)
    assert "read 3 times for this recipe family (fb)" in card and "not held-out evidence for the change" in card
