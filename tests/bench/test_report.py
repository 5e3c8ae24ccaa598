import json

from neuraldem.bench.report import default_path, machine_info, write_results
from neuraldem.paths import results_dir


def test_default_location_is_results_bench():
    assert default_path("x") == results_dir() / "bench" / "x.json"


def test_write_results(tmp_path):
    path = write_results("demo", [{"a": 1}], command="python -m neuraldem.bench demo",
                         path=tmp_path / "sub" / "demo.json", machine={"cpu_model": "test"})
    data = json.loads(path.read_text())
    assert data["results"] == [{"a": 1}] and data["machine"] == {"cpu_model": "test"}
    assert set(data) == {"benchmark", "date", "command", "machine", "results"}


def test_machine_info_describes_this_machine():
    info = machine_info()
    assert info["cpu_count"] >= 1 and info["torch"] and info["cpu_model"]
