"""The one argument grammar (`neuraldem.cli`): key=value for every option, lists and booleans, each key once,
unknown keys listed, old flag spellings accepted with a note naming the new form, errors in one line."""

from __future__ import annotations

from pathlib import Path

import pytest

from neuraldem.cli import CommandParser, check_overrides, output_folder
from neuraldem.errors import ConfigError


def parser() -> CommandParser:
    p = CommandParser(prog="neuraldem bench demo")
    p.add_argument("--ckpt", type=Path, required=True)
    p.add_argument("--n-velocities", type=int, default=7)
    p.add_argument("--labels", nargs="+", default=None)
    p.add_argument("--mirror-alternate", action="store_true")
    p.add_argument("--no-fields", dest="fields", action="store_false")
    p.add_argument("--param", action="append", default=[])
    return p


def test_key_value_options_lists_and_booleans():
    a = parser().parse_args(["ckpt=a.ckpt", "n_velocities=3", "labels=[x,y]", "mirror_alternate=true",
                             "fields=false", "param=[alpha=30,mu_s=0.4]"])
    assert (a.ckpt, a.n_velocities, a.labels, a.mirror_alternate, a.fields) == (Path("a.ckpt"), 3, ["x", "y"], True,
                                                                                 False)
    assert a.param == ["alpha=30", "mu_s=0.4"]
    b = parser().parse_args(["ckpt=a.ckpt", "mirror_alternate=false"])
    assert b.mirror_alternate is False and b.fields is True and b.n_velocities == 7


def one_line_failure(capsys, argv: list[str]) -> str:
    with pytest.raises(SystemExit) as done:
        parser().parse_args(argv)
    err = capsys.readouterr().err
    assert done.value.code == 2 and err.count("\n") == 1 and err.startswith("neuraldem: error: "), err
    return err


def test_a_key_given_twice_is_refused(capsys):
    assert "n_velocities= is given twice" in one_line_failure(capsys, ["ckpt=a", "n_velocities=1", "n_velocities=2"])


def test_an_unknown_key_lists_the_options(capsys):
    err = one_line_failure(capsys, ["ckpt=a", "steps=3"])
    assert "unknown option steps=: the options are ckpt=, n_velocities=, labels=, mirror_alternate=" in err


def test_argparse_errors_speak_the_grammar(capsys):
    assert "option n_velocities=: invalid int value: 'x'" in one_line_failure(capsys, ["ckpt=a", "n_velocities=x"])
    assert "required: ckpt=" in one_line_failure(capsys, ["n_velocities=2"])
    assert "mirror_alternate='maybe' is not a boolean" in one_line_failure(capsys, ["ckpt=a", "mirror_alternate=maybe"])


def test_old_flags_still_work_and_print_the_new_spelling(capsys):
    a = parser().parse_args(["--ckpt", "a.ckpt", "--n-velocities", "3", "--mirror-alternate", "--no-fields"])
    assert (a.ckpt, a.n_velocities, a.mirror_alternate, a.fields) == (Path("a.ckpt"), 3, True, False)
    err = capsys.readouterr().err
    assert "old spelling" in err and "ckpt=a.ckpt n_velocities=3 mirror_alternate=true fields=false" in err


def test_help_shows_key_value_options(capsys):
    with pytest.raises(SystemExit):
        parser().parse_args(["--help"])
    out = capsys.readouterr().out
    assert "ckpt=CKPT" in out and "mirror_alternate=true|false" in out and "--n-velocities" not in out


def test_an_output_folder_that_cannot_be_created_is_named_with_the_reason(tmp_path: Path):
    assert output_folder(tmp_path / "a" / "b").is_dir()
    with pytest.raises(ConfigError, match=r"out=/proc/x: the folder cannot be created \(.*\)"):
        output_folder(Path("/proc/x"))


def test_hydra_overrides_each_once_and_known(capsys):
    check_overrides("train", ["experiment=hopper_micro", "data.datamodule.batch_size=4", "+extra=1", "-m"])
    with pytest.raises(SystemExit):
        check_overrides("train", ["seed=1", "seed=2"])
    assert "seed= is given twice" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        check_overrides("train", ["sede=1"])
    err = capsys.readouterr().err
    assert "unknown option sede=: the options are" in err and "experiment=" in err and "seed=" in err


def test_every_tools_output_option_is_checked_when_parsed(capsys):
    p = CommandParser(prog="neuraldem report demo")
    p.add_argument("--out", type=Path, required=True)
    with pytest.raises(SystemExit):
        p.parse_args(["out=/proc/x/report"])
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "out=/proc/x/report: the folder cannot be created" in err


def test_an_old_flag_takes_its_values_even_when_they_look_like_keys():
    a = parser().parse_args(["ckpt=a", "--param", "alpha=30", "--labels", "x", "y", "n_velocities=2"])
    assert a.param == ["alpha=30"] and a.labels == ["x", "y"] and a.n_velocities == 2


def test_a_bare_choice_of_a_positional_is_the_commands_object(capsys):
    p = CommandParser(prog="neuraldem export")
    p.add_argument("format", choices=["gns", "lagrangebench"])
    p.add_argument("dataset")
    a = p.parse_args(["gns", "dataset=d"])
    assert (a.format, a.dataset) == ("gns", "d") and capsys.readouterr().err == ""
    b = p.parse_args(["dataset=d", "lagrangebench"])  # anywhere on the line
    assert (b.format, b.dataset) == ("lagrangebench", "d")
    with pytest.raises(SystemExit):
        p.parse_args(["gns", "format=gns", "dataset=d"])
    assert "format= is given twice" in capsys.readouterr().err


def test_help_shows_the_object_bare_and_a_subcommand_once(capsys):
    p = CommandParser(prog="neuraldem export")
    p.add_argument("format", choices=["gns", "lagrangebench"])
    p.add_argument("--out", required=True)
    with pytest.raises(SystemExit):
        p.parse_args(["--help"])
    assert capsys.readouterr().out.startswith("usage: neuraldem export gns|lagrangebench out=OUT\n")
    q = CommandParser(prog="neuraldem export")
    q.add_subparsers(dest="cmd").add_parser("pack").add_argument("dataset")
    with pytest.raises(SystemExit):
        q.parse_args(["pack", "--help"])
    assert capsys.readouterr().out.startswith("usage: neuraldem export pack dataset=DATASET\n")
