import json

from neuraldem.bench.__main__ import main as bench_main


def test_model_step_writes_timings_with_machine_info(tmp_path, capsys):
    out = tmp_path / "model_step.json"
    argv = ["configs=[hopper_tiny,fb_tiny]", "threads=[1,2]", "repeats=1", "warmup=0", "batch_size=1", "n_queries=16",
            "n_particles=64", f"out={out}"]
    assert bench_main(["model_step", *argv]) == 0
    data = json.loads(out.read_text())
    assert data["benchmark"] == "model_step"
    assert data["command"].startswith("neuraldem bench model_step 'configs=[hopper_tiny,fb_tiny]' 'threads=[1,2]'")
    assert data["date"]
    machine = data["machine"]
    for key in ("cpu_model", "cpu_count", "torch", "torch_threads_default", "load_average_1_5_15min"):
        assert machine[key] is not None, key
    records = data["results"]
    assert [(r["config"], r["threads"]) for r in records] == [
        ("hopper_tiny", 1), ("hopper_tiny", 2), ("fb_tiny", 1), ("fb_tiny", 2)]
    for r in records:
        assert r["median_ms"] > 0 and len(r["times_ms"]) == 1 and r["parameters"] > 0
        assert r["workload"]["batch_size"] == 1
    assert "fb_tiny" in capsys.readouterr().out
