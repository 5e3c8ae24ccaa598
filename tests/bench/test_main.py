from neuraldem.bench.__main__ import BENCHMARKS, entry_point, main


def test_lists_benchmarks_without_arguments(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in BENCHMARKS)


def test_unknown_benchmark_is_an_error(capsys):
    assert main(["nope"]) == 2
    assert "unknown benchmark" in capsys.readouterr().err


def test_config_errors_are_one_line(capsys):
    assert main(["model_step", "--configs", "no_such_model", "--repeats", "1"]) == 2
    assert "no_such_model" in capsys.readouterr().err


def test_every_benchmark_has_an_entry_point():
    for name in BENCHMARKS:
        assert callable(entry_point(name)), name
