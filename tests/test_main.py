"""`neuraldem COMMAND`: every listed command resolves to a module with a main(), nested groups work, unknown
commands fail with the choices, and a command's own --help runs under its new name."""

from __future__ import annotations

import importlib

import pytest

from neuraldem.__main__ import COMMANDS, main, resolve
from tests.helpers import run_module


def _leaves(group, prefix=()):
    for name, entry in group.items():
        if isinstance(entry, tuple):
            yield (*prefix, name), entry[0]
        else:
            yield from _leaves(entry, (*prefix, name))


@pytest.mark.parametrize(("words", "module"), list(_leaves(COMMANDS)))
def test_every_command_resolves_to_a_module_with_main(words, module):
    prog, resolved, args = resolve([*words, "--x"])
    assert prog == "neuraldem " + " ".join(words) and resolved == module and args == ["--x"]
    assert callable(importlib.import_module(module).main)


def test_groups_unknown_commands_and_help(capsys):
    assert main([]) == 0 and "evaluate" in capsys.readouterr().out
    assert main(["report"]) == 0 and "fb-baselines" in capsys.readouterr().out
    assert main(["report", "nope"]) == 2
    assert "unknown command 'nope': choose from dataset, fb-dataset" in capsys.readouterr().err
    assert resolve(["report", "fb_table"])[1] == "neuraldem.scenes.fluidized_bed.analysis.table"  # _ and - both work


def test_a_tool_and_a_hydra_command_run_through_the_console_entry():
    proc = run_module("neuraldem", "report", "fb-baselines", "--help")
    assert proc.returncode == 0, proc.stderr
    assert "usage: neuraldem report fb-baselines" in proc.stdout
    proc = run_module("neuraldem", "evaluate", "--help")
    assert proc.returncode == 0 and "`neuraldem evaluate` takes Hydra overrides" in proc.stdout
    proc = run_module("neuraldem", "evaluate")  # a missing required value is one line, exit 2
    assert proc.returncode == 2 and "ckpt=" in proc.stderr
