"""`neuraldem VERB`: about twelve verbs (at most 13), each with a line and an example; every verb and group entry
resolves to a module with a main(); the scenes' reports, benchmarks and importers are reachable; old verbs print the
new form; an unknown verb lists the verbs."""

from __future__ import annotations

import importlib

import pytest

from neuraldem.__main__ import VERBS, groups, main, resolve
from tests.helpers import run_module


def test_about_twelve_verbs_each_with_an_example(capsys):
    assert len(VERBS) <= 13
    assert main([]) == 0
    out = capsys.readouterr().out
    for verb, (_, text, example) in VERBS.items():
        assert f"  {verb} " in out and text in out and example.startswith("neuraldem") and example in out


@pytest.mark.parametrize("verb", [v for v, (module, _, _) in VERBS.items() if module])
def test_every_verb_resolves_to_a_module_with_main(verb):
    prog, module, args = resolve([verb, "x=1"])
    assert prog == f"neuraldem {verb}" and args == ["x=1"]
    assert callable(importlib.import_module(module).main)


@pytest.mark.parametrize(("verb", "name", "module"),
                         [(v, n, e[0]) for v, entries in groups().items() for n, e in entries.items()])
def test_every_group_entry_resolves_to_a_module_with_main(verb, name, module):
    assert resolve([verb, name, "x=1"]) == (f"neuraldem {verb} {name}", module, ["x=1"])
    assert callable(importlib.import_module(module).main)


def test_the_scenes_bring_their_reports_and_importers(capsys):
    assert main(["report"]) == 0
    out = capsys.readouterr().out
    assert "hopper-cv" in out and "fb-baselines" in out and "refill-table" in out and "dataset" in out
    assert main(["import", "--help"]) == 0 and "liggghts" in capsys.readouterr().out
    assert resolve(["report", "fb_table"])[1] == "neuraldem.scenes.fluidized_bed.analysis.table"  # _ and - both


def test_unknown_verbs_and_names_list_the_choices(capsys):
    assert main(["frobnicate"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown verb 'frobnicate': the verbs are doctor, scene, datagen, train" in err
    assert main(["report", "nope"]) == 2
    assert "unknown report 'nope': choose from dataset, step-displacement" in capsys.readouterr().err


def test_old_verbs_print_the_new_spelling_and_still_run(capsys):
    assert resolve(["rollout", "ckpt=x"]) == ("neuraldem evaluate rollout", "neuraldem.rollout", ["ckpt=x"])
    assert "`neuraldem rollout` is `neuraldem evaluate rollout` now" in capsys.readouterr().err
    assert resolve(["transfer", "pack"])[:2] == ("neuraldem export", "neuraldem.export.__main__")


def test_a_tool_and_a_hydra_command_run_through_the_console_entry():
    proc = run_module("neuraldem", "report", "fb-baselines", "--help")
    assert proc.returncode == 0, proc.stderr
    assert "usage: neuraldem report fb-baselines" in proc.stdout and "out=" in proc.stdout
    proc = run_module("neuraldem", "evaluate", "--help")
    assert proc.returncode == 0 and "`neuraldem evaluate` takes Hydra overrides" in proc.stdout
    proc = run_module("neuraldem", "evaluate")  # a missing required value is one line, exit 2
    assert proc.returncode == 2 and "ckpt=" in proc.stderr


def test_a_tool_started_as_a_module_names_its_command():
    """`python -m neuraldem.<module>` still runs a tool; its usage line and errors name the documented command."""
    proc = run_module("neuraldem.scenes.hopper.analysis.cv", "--help")
    assert proc.returncode == 0 and proc.stdout.startswith("usage: neuraldem report hopper-cv ")
    proc = run_module("neuraldem.export", "gns", "no_such_key=1")
    assert proc.returncode == 2 and proc.stderr.startswith("neuraldem: error: neuraldem export: unknown option")
