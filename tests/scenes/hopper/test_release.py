"""The shipped pretrained models: they load by name, every file is checked, and they give the answers stored
when they were built (the probe points in meta.json); a missing or damaged file names itself and the rebuild."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from neuraldem import pretrained
from neuraldem.errors import ConfigError, DataError

SHIPPED = Path(pretrained.__file__).parent


@pytest.fixture
def own_copy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A copy of the shipped folder that the loader reads instead (to damage without touching the package)."""
    folder = tmp_path / "pretrained"
    shutil.copytree(SHIPPED, folder, ignore=shutil.ignore_patterns("*.py", "__pycache__"))
    monkeypatch.setenv("NEURALDEM_PRETRAINED_DIR", str(folder))
    return folder


def test_the_hopper_model_is_shipped_small_and_documented():
    assert "hopper_small" in pretrained.names()
    model = pretrained.load("hopper_small", "hopper")
    meta = model.meta
    assert meta["inputs"] == ["alpha", "mu_s", "mu_r"]
    for role in ("field", "gp"):
        assert model.file(role).stat().st_size < 5e6  # a few MB at most
    assert len(meta["training_data"]["manifest_sha256"]) == 64 and meta["training_data"]["run_ids"]["train"]
    errors = meta["test_errors"]
    assert errors["n_test_runs"] >= 10 and {"field model", "gp", "constant"} <= set(errors)
    assert meta["rebuild"][0].startswith("neuraldem train") and meta["rebuild"][1].startswith("neuraldem release ")


def test_shipped_files_reproduce_their_stored_probe_answers():
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess, gp_answers
    from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings
    from neuraldem.scenes.hopper.predict import hopper_module
    from neuraldem.scenes.hopper.whatif import field_answer

    model = pretrained.load("hopper_small")
    gp = ArrayGaussianProcess.load_npz(model.file("gp"))
    module = hopper_module(model)
    settings = HopperMetricSettings.from_config(model.meta["metric_settings"], "meta")
    for probe in model.meta["probes"]:
        answer = gp_answers(gp, [probe["parameters"]])[0]
        for key, value in probe["gp_mean"].items():
            assert answer.mean[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
        f = field_answer(module.net, module.metadata, probe["parameters"], settings,
                         time_stride=probe["field_time_stride"])
        for key, value in probe["field_summary"].items():
            assert f.summary[key] == pytest.approx(value, rel=1e-3, abs=1e-4), key


def test_unknown_model_lists_the_shipped_ones():
    with pytest.raises(ConfigError, match="unknown pretrained model 'nope'.*hopper_small"):
        pretrained.load("nope")


@pytest.mark.parametrize("damage", ["missing", "flipped byte"])
def test_a_missing_or_damaged_file_names_itself_and_the_rebuild(own_copy: Path, damage: str):
    from tests.helpers import flip_byte

    path = own_copy / "hopper_small" / "gp.npz"
    if damage == "missing":
        path.unlink()
    else:
        flip_byte(path)
    with pytest.raises(DataError) as err:
        pretrained.load("hopper_small").file("gp")
    text = str(err.value)
    assert str(path) in text and ("missing" if damage == "missing" else "damaged") in text
    assert "neuraldem train" in text and "&& neuraldem release ckpt=" in text


def test_an_unreadable_meta_is_one_error(own_copy: Path):
    (own_copy / "hopper_small" / "meta.json").write_text("{")
    with pytest.raises(DataError, match="meta.json is unreadable"):
        pretrained.load("hopper_small")


def test_the_tiny_build_records_what_it_was_built_from(tiny_pretrained: Path):
    meta = json.loads((tiny_pretrained / "hopper_tiny_test" / "meta.json").read_text())
    assert meta["training_data"]["dataset"] == "hopper_tiny" and meta["kind"] == "hopper"
    assert np.isfinite(meta["test_errors"]["field model"]["drainage_t95_pct_of_mean"])
    assert os.path.getsize(tiny_pretrained / "hopper_tiny_test" / "field.pt") < 2e6


@pytest.mark.slow
def test_the_stored_test_errors_are_reproduced_on_the_training_dataset(tmp_path: Path):
    """With hopper_small at hand (NEURALDEM_SHIPPED_DATASETS, default the user's data dir: the tests' own data dir
    never holds it), scoring the shipped field model on its test runs again gives the errors meta.json states.
    Skipped where the dataset is absent (CI)."""
    from neuraldem.data.integrity import digest
    from neuraldem.scenes.hopper.analysis.evaluation import evaluate_checkpoint

    model = pretrained.load("hopper_small")
    datasets = Path(os.environ.get("NEURALDEM_SHIPPED_DATASETS", Path.home() / ".local/share/neuraldem/datasets"))
    dataset = datasets / model.meta["training_data"]["dataset"]
    if not (dataset / "manifest.json").is_file():
        pytest.skip(f"no {dataset}")
    if digest(dataset / "manifest.json") != model.meta["training_data"]["manifest_sha256"]:
        pytest.skip(f"{dataset} is not the dataset the model was built from (its manifest changed)")
    result = evaluate_checkpoint(model.file("field"), tmp_path, dataset.parent, dataset, vtk=False, progress=False)
    stored = model.meta["test_errors"]

    def errors(agg: dict) -> dict:  # the answer time is not an error and varies with the machine
        return {k: v for k, v in agg.items() if k not in ("answer_s", "fit_s")}

    assert errors(result["aggregate"]) == pytest.approx(errors(stored["field model"]), rel=1e-6, abs=1e-9,
                                                        nan_ok=True)
    assert errors(result["baselines"]["gp"]["aggregate"]) == pytest.approx(errors(stored["gp"]), rel=1e-6,
                                                                           nan_ok=True)
