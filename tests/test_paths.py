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


def test_invocation_names_a_package_script_by_the_command_that_runs_it(monkeypatch, tmp_path):
    monkeypatch.setenv(paths.ENV_VAR, str(tmp_path))
    package = paths.Path(paths.__file__).resolve().parent
    argv = [str(package / "train.py"), "experiment=fb", f"hydra.run.dir={tmp_path}/fb/run"]
    assert paths.invocation(argv) == "neuraldem train experiment=fb hydra.run.dir=$NEURALDEM_DATA/fb/run"
    argv = [str(package / "scenes/fluidized_bed/analysis/baselines.py"), "dataset=fb_small"]
    assert paths.invocation(argv) == "neuraldem report fb-baselines dataset=fb_small"
    assert paths.invocation([str(package / "datagen/__main__.py")]) == "neuraldem datagen"
    # a module no verb runs keeps python -m; a script outside the package keeps its path
    assert paths.invocation([str(package / "eval/current_weights.py"), "a", "b"]) == \
        "python -m neuraldem.eval.current_weights a b"
    assert paths.invocation(["/opt/tool.py", "-v"]) == "/opt/tool.py -v"


def test_module_command_records_the_command_with_the_arguments_portably(monkeypatch, tmp_path):
    monkeypatch.setenv(paths.ENV_VAR, str(tmp_path))
    assert paths.module_command("neuraldem.scenes.hopper.analysis.cv", [f"out={tmp_path}/cv.md"]) == \
        "neuraldem report hopper-cv out=$NEURALDEM_DATA/cv.md"
    monkeypatch.setattr(paths.sys, "argv", ["/x/cv.py", "folds=[1]"])  # default: this process's arguments
    assert paths.module_command("neuraldem.scenes.hopper.analysis.cv") == "neuraldem report hopper-cv folds=[1]"


def test_every_tool_module_is_named_by_its_command():
    from neuraldem.commands import command_of

    assert command_of("neuraldem.bench fb_speed") == "neuraldem bench fb_speed"
    assert command_of("neuraldem.predict hopper") == "neuraldem predict hopper"
    assert command_of("neuraldem.rollout") == "neuraldem evaluate rollout"
    assert command_of("neuraldem.export.__main__") == "neuraldem export"
    assert command_of("neuraldem.scenes.fluidized_bed.dataset.importer") == "neuraldem import foam"
    assert command_of("neuraldem.scenes.hopper.dataset.transfer") == "neuraldem export"
    assert command_of("neuraldem.scenes.hopper.release") == "neuraldem release"
    assert command_of("neuraldem.eval.dataset_report") == "neuraldem report dataset"
    assert command_of("neuraldem.eval.current_weights") is None
