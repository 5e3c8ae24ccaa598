"""Recorded commands read the same on every machine: no data dir or checkout path of the machine that ran them."""

from __future__ import annotations

from neuraldem import paths


def test_portable_writes_the_data_dir_as_the_variable_and_drops_the_checkout(monkeypatch, tmp_path):
    monkeypatch.setenv(paths.ENV_VAR, str(tmp_path / "data"))
    root = paths.repo_root()
    assert root is not None  # the tests run from the checkout
    text = f"python {root}/scripts/x.py ckpt={tmp_path}/data/fb/last.ckpt out={root}/results/t.md keep=/elsewhere/a"
    assert paths.portable(text) == \
        "python scripts/x.py ckpt=$NEURALDEM_DATA/fb/last.ckpt out=results/t.md keep=/elsewhere/a"


def test_invocation_names_a_package_script_by_its_module(monkeypatch, tmp_path):
    monkeypatch.setenv(paths.ENV_VAR, str(tmp_path))
    package = paths.Path(paths.__file__).resolve().parent
    argv = [str(package / "train.py"), "experiment=fb", f"hydra.run.dir={tmp_path}/fb/run"]
    assert paths.invocation(argv) == "python -m neuraldem.train experiment=fb hydra.run.dir=$NEURALDEM_DATA/fb/run"
    argv = [str(package / "scenes/fluidized_bed/analysis/baselines.py"), "fb_small"]
    assert paths.invocation(argv) == "python -m neuraldem.scenes.fluidized_bed.analysis.baselines fb_small"
    assert paths.invocation([str(package / "datagen/__main__.py")]) == "python -m neuraldem.datagen"
    # a script outside the package keeps its path
    assert paths.invocation(["/opt/tool.py", "-v"]) == "/opt/tool.py -v"


def test_module_command_records_python_m_with_the_arguments_portably(monkeypatch, tmp_path):
    monkeypatch.setenv(paths.ENV_VAR, str(tmp_path))
    assert paths.module_command("neuraldem.scenes.hopper.analysis.cv", ["--out", f"{tmp_path}/cv.md"]) == \
        "python -m neuraldem.scenes.hopper.analysis.cv --out $NEURALDEM_DATA/cv.md"
    monkeypatch.setattr(paths.sys, "argv", ["/x/cv.py", "--folds", "1"])  # default: this process's arguments
    assert paths.module_command("neuraldem.scenes.hopper.analysis.cv") == \
        "python -m neuraldem.scenes.hopper.analysis.cv --folds 1"
