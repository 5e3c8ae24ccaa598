import json

import pytest

from neuraldem.bench.report import (
    RESULT_FOLDERS,
    command_line,
    default_path,
    machine_info,
    read_results,
    warn_if_busy,
    write_results,
)
from neuraldem.errors import DataError
from neuraldem.paths import results_dir


def test_an_unlisted_benchmark_writes_to_results_bench():
    assert default_path("x") == results_dir() / "bench" / "x.json"


def test_every_benchmark_writes_into_the_folder_of_its_question():
    from neuraldem.bench.__main__ import benchmarks

    assert (set(benchmarks()) - {"all", "render"}) | {"serve_latency_fb"} == set(RESULT_FOLDERS)
    for name, folder in RESULT_FOLDERS.items():
        assert default_path(name) == results_dir() / folder / f"{name}.json"
        assert default_path(name).parent.is_dir(), f"{name}: results/{folder}/ is not in the checkout"


def test_write_results(tmp_path):
    path = write_results("demo", [{"a": 1}], command="neuraldem bench demo",
                         path=tmp_path / "sub" / "demo.json", machine={"cpu_model": "test"})
    data = json.loads(path.read_text())
    assert data["results"] == [{"a": 1}] and data["machine"] == {"cpu_model": "test"}
    assert set(data) == {"benchmark", "date", "command", "machine", "results"}


def test_machine_info_describes_this_machine():
    info = machine_info()
    assert info["cpu_count"] >= 1 and info["torch"] and info["cpu_model"]


def test_write_is_atomic_and_read_back(tmp_path):
    path = write_results("demo", {"x": 1}, command="c", path=tmp_path / "demo.json", machine={})
    assert read_results(path, "demo")["results"] == {"x": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["demo.json"]  # no temporary file left behind


def test_read_results_errors(tmp_path):
    with pytest.raises(DataError, match="no results at"):
        read_results(tmp_path / "none.json", "demo")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(DataError, match="not valid JSON"):
        read_results(tmp_path / "bad.json", "demo")
    path = write_results("other", {}, command="c", path=tmp_path / "other.json", machine={})
    with pytest.raises(DataError, match="holds results of benchmark 'other', not 'demo'"):
        read_results(path, "demo")


def test_busy_machine_warning(capsys):
    assert warn_if_busy({"load_average_1_5_15min": [0.1, 0.1, 0.1]}) is None
    assert "quiet machine" in warn_if_busy({"load_average_1_5_15min": [1.9, 1.0, 1.0]})
    assert "load average 1.90" in capsys.readouterr().err
    assert command_line("x", ["a=1", "note=b c"]) == "neuraldem bench x a=1 'note=b c'"


def test_machine_at_start_describes_the_machine_and_warns_when_busy(monkeypatch, capsys):
    import neuraldem.bench.report as report

    monkeypatch.setattr(report, "machine_info", lambda: {"load_average_1_5_15min": [3.0, 1.0, 1.0]})
    assert report.machine_at_start()["load_average_1_5_15min"][0] == 3.0
    assert "quiet machine" in capsys.readouterr().err
