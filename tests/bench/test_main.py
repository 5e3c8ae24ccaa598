from neuraldem.bench.__main__ import benchmarks, by_scene, entry_point, main


def test_lists_benchmarks_by_scene_without_arguments(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in benchmarks())
    assert "across scenes and models:" in out and "\nhopper:" in out and "\nfluidized_bed:" in out
    assert "fb_speed" in by_scene()["fluidized_bed"] and "hopper_speed" in by_scene()["hopper"]


def test_unknown_benchmark_is_an_error(capsys):
    assert main(["nope"]) == 2
    assert "unknown benchmark 'nope': choose one of model_step" in capsys.readouterr().err


def test_config_errors_are_one_line(capsys):
    assert main(["model_step", "configs=[no_such_model]", "repeats=1"]) == 2
    assert "no_such_model" in capsys.readouterr().err


def test_every_benchmark_has_an_entry_point():
    for name in benchmarks():
        assert callable(entry_point(name)), name
