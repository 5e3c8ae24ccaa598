"""Cost scaling: the log-log figure from a hand-made results dict, the surrogate sweep on a fake clock, a
tiny real LIGGGHTS sweep (measured + extrapolated) and one-line errors for bad options."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.bench import plots
from neuraldem.bench.__main__ import main as bench_main
from neuraldem.scenes.hopper.bench import scaling as hopper_scaling
from neuraldem.scenes.hopper.bench.surrogate import untrained_surrogate
from tests.bench.test_timing import FakeClock

HAND_MADE = {
    "solver": {"points": [
        {"n_particles": n, "steps_per_drain_chunk": 1000, "measured": {"process_wall_s": 0.01 * n},
         "extrapolated": {"full_run_s": 0.02 * n}} for n in (2000, 5000, 10000)]},
    "surrogate": {"n_times": 81, "by_queries": [{"n_queries": q, "median_wall_s": 1e-5 * q} for q in (1000, 5000)],
                  "by_tokens": [{"n_latent_tokens": k, "n_queries": 5000, "median_wall_s": 0.01 * k} for k in (8, 16)]},
}
HAND_MADE["solver"]["points"][1]["full_run_measured"] = {"loop_s": 90.0}
HAND_MADE["solver"]["points"].append({"n_particles": 50000, "failed": "LIGGGHTS shortened run failed: test"})


def test_scaling_plot_is_written(tmp_path: Path):
    path = plots.scaling_figure(HAND_MADE, tmp_path / "scaling.png")
    assert path.is_file() and path.stat().st_size > 10_000
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_surrogate_sweep_on_a_fake_clock(monkeypatch: pytest.MonkeyPatch):
    fake = FakeClock()
    monkeypatch.setattr(hopper_scaling, "answer", lambda s, q: fake.advance(1e-6 * len(q.points), 0.0))
    s = untrained_surrogate("hopper_tiny", hopper_scaling.CONDITIONING)
    out = hopper_scaling.surrogate_scaling(s, "hopper_tiny", queries=[10, 100], tokens=[4, 8], token_queries=50,
                                           n_times=3, repeats=2, threads=1, clock=fake.clock())
    assert [r["median_wall_s"] for r in out["by_queries"]] == pytest.approx([1e-5, 1e-4])
    assert [r["median_wall_s"] for r in out["by_tokens"]] == pytest.approx([5e-5, 5e-5])
    assert out["by_tokens"][1]["parameters"] > out["by_tokens"][0]["parameters"]
    assert out["weights"].startswith("untrained")


@pytest.mark.solver
def test_tiny_real_sweep(hopper_tiny_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture):
    out = tmp_path / "scaling.json"
    argv = ["hopper_scaling", f"dataset={hopper_tiny_dataset}", "particles=[150,300]", "steps=100", "full_up_to=150",
            "model=hopper_tiny", "queries=[50,100]", "tokens=[4,8]", "token_queries=50", "n_times=3", "repeats=1",
            f"workdir={tmp_path / 'w'}", f"out={out}"]
    assert bench_main(argv) == 0
    r = json.loads(out.read_text())["results"]
    small, large = r["solver"]["points"]
    assert (small["n_particles"], large["n_particles"]) == (150, 300)
    for pt in (small, large):
        assert pt["measured"]["drain_particle_steps_per_s"] > 0 and pt["measured"]["settle_s"] > 0
        assert pt["extrapolated"]["full_run_s"] > pt["measured"]["settle_s"]
        assert pt["repeats"][0]["drain_chunks"] in (1, 2)
    assert "full_run_measured" in small and "full_run_measured" not in large
    assert r["solver"]["drain_profile"]["source"].startswith("median over")
    assert out.with_suffix(".png").is_file()
    assert "extrapolated" in capsys.readouterr().out


def test_bad_options_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture):
    base = ["hopper_scaling", "skip_solver=true", "model=hopper_tiny", f"out={tmp_path / 'x.json'}"]
    assert bench_main([*base, "drain_time=3"]) == 2
    assert "drain_time= and remaining_fraction= go together" in capsys.readouterr().err
    assert bench_main([*base, "param=[gamma=1]"]) == 2
    assert "config value param='gamma' is invalid" in capsys.readouterr().err
    assert bench_main([*base, "queries=[0]"]) == 2
    assert "config value queries=0 is invalid" in capsys.readouterr().err
    assert bench_main([*base, f"reuse_solver={tmp_path / 'missing.json'}"]) == 2
    assert "no results at" in capsys.readouterr().err
