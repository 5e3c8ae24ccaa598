"""The solver's noise floor: the spread arithmetic, the parameter-set choice, option errors, and real reruns of
the tiny dataset with new packing seeds (cached: a second call runs no solver)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from neuraldem.bench.__main__ import main as bench_main
from neuraldem.scenes.hopper.bench import seed_floor
from neuraldem.scenes.hopper.bench.seed_floor import farthest_points, rerun_index, seed_spread
from neuraldem.sim.seeds import prime_seeds

pytestmark = pytest.mark.solver


def _m(t95: float, residual: float, outflow: float, regime: float = 1.0) -> dict[str, float]:
    return {"drainage_t95": t95, "drainage_time": t95, "residual_fraction": residual,
            "residual_fraction_particles": residual, "outflow_rate": outflow, "mass_flow_index": 0.5,
            "mass_flow": regime}


def test_spread_on_hand_written_numbers():
    groups = [[_m(1.0, 0.1, 1.0), _m(3.0, 0.3, 3.0, regime=0.0)],  # std sqrt(2) / 0.1 sqrt(2) / sqrt(2)
              [_m(2.0, 0.0, 2.0), _m(2.0, 0.0, 2.0)],  # no spread
              [_m(5.0, 0.0, math.nan)]]  # one run only: left out
    s = seed_spread(groups)
    assert s["drainage_t95"]["value"] == pytest.approx(100 * (math.sqrt(2) / 2) / 2)  # mean std / mean of means
    assert s["drainage_t95"]["n_sets"] == 2 and s["drainage_t95"]["comparable_error"] == "drainage_t95_pct_of_mean"
    assert s["residual_fraction"]["value"] == pytest.approx(100 * 0.1 * math.sqrt(2) / 2)  # percentage points
    assert s["outflow_rate"]["value"] == pytest.approx(100 * (math.sqrt(2) / 2 + 0) / 2)  # std / set mean
    assert s["mass_flow_index"]["value"] == pytest.approx(0.0)
    assert s["mass_flow"]["value"] == pytest.approx(2 / 3)  # the first set changes regime


def test_parameter_sets_are_spread_and_reproducible():
    x = np.array([[0.0, 0.0], [0.01, 0.0], [1.0, 1.0], [0.0, 1.0], [0.5, 0.5]])
    picked = farthest_points(x, 3, seed=0)
    assert picked == farthest_points(x, 3, seed=0) and len(set(picked)) == 3
    assert not {0, 1} <= set(picked)  # never both of the near-duplicates
    assert len(set(farthest_points(np.zeros((4, 2)), 4, seed=1))) == 4  # duplicates are still distinct runs


def test_rerun_seeds_differ_from_stored_runs():
    stored = {s for i in range(50) for s in prime_seeds(i, 3)}
    reruns = {s for i in range(50) for k in (1, 2, 3) for s in prime_seeds(rerun_index(i, k), 3)}
    assert not stored & reruns and max(reruns) < 2**31 - 1


@pytest.mark.parametrize("args, message", [(["seeds=0"], "config value seeds=0 is invalid"),
                                           (["n_sets=0"], "config value n_sets=0 is invalid"),
                                           (["n_sets=99"], "fewer than n_sets=99: pass n_sets=8 or less")])
def test_bad_options_are_one_line_errors(hopper_tiny_dataset: Path, tmp_path: Path, capsys, args, message):
    argv = ["seed_floor", f"dataset={hopper_tiny_dataset}", f"workdir={tmp_path}", *args]
    assert bench_main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("neuraldem: error: ") and err.count("\n") == 1 and message in err, err


def test_a_cache_of_other_runs_is_refused(hopper_tiny_dataset: Path, tmp_path: Path, capsys):
    (tmp_path / "reruns.json").write_text(json.dumps({"header": {"version": 1, "seed_offset": 7}, "runs": {}}))
    argv = ["seed_floor", f"dataset={hopper_tiny_dataset}", "n_sets=1", f"workdir={tmp_path}"]
    assert bench_main(argv) == 2
    assert "reruns.json holds reruns made with another scene, seed_offset: delete it" in capsys.readouterr().err


def test_reruns_scored_and_cached(hopper_tiny_dataset: Path, tmp_path: Path, monkeypatch, capsys):
    out, work = tmp_path / "seed_floor.json", tmp_path / "work"
    argv = ["seed_floor", f"dataset={hopper_tiny_dataset}", "n_sets=2", "seeds=1", f"workdir={work}", f"out={out}"]
    assert bench_main(argv) == 0
    payload = json.loads(out.read_text())
    r = payload["results"]
    assert payload["benchmark"] == "seed_floor" and payload["machine"]["cpu_count"] >= 1
    assert len(r["selection"]["sim_ids"]) == 2 and len(r["runs"]) == 2 and r["counts"]["ok"] == 2, r["runs"]
    for run in r["runs"]:
        assert run["run_index"] == seed_floor.SEED_OFFSET + int(run["index"]) and run["cpu_s"] > 0
    for key in ("drainage_t95_pct_of_mean", "drainage_mae_pct_of_mean", "residual_mae_pp", "outflow_rel_err_pct"):
        assert math.isfinite(r["rerun_vs_stored"][key]) and r["point"]["errors"][key] == r["rerun_vs_stored"][key]
    for key in ("drainage_t95", "drainage_time", "residual_fraction", "outflow_rate"):
        assert math.isfinite(r["seed_spread"][key]["value"]) and r["seed_spread"][key]["n_sets"] == 2
    assert r["cost"]["cpu_s_per_rerun_median"] > 0
    assert "rerun vs stored" in out.with_suffix(".md").read_text()
    cached = json.loads((work / "reruns.json").read_text())["runs"]
    assert sorted(cached) == sorted(f"{s}/seed1" for s in r["selection"]["sim_ids"])

    def no_solver(*args, **kwargs):
        raise AssertionError("the solver ran although every rerun is cached")

    monkeypatch.setattr(seed_floor, "run_scene", no_solver)
    out2 = tmp_path / "again.json"
    assert bench_main([*argv[:-1], f"out={out2}"]) == 0
    assert json.loads(out2.read_text())["results"]["seed_spread"] == r["seed_spread"]

    # new metric settings: the stored reruns are rescored from their files, still without the solver
    cache = json.loads((work / "reruns.json").read_text())
    cache["header"]["metric_settings"]["tail_time"] = 0.5
    (work / "reruns.json").write_text(json.dumps(cache))
    assert all((work / row["file"]).is_file() for row in cache["runs"].values())
    assert bench_main([*argv[:-1], f"out={tmp_path / 'third.json'}"]) == 0
    header = json.loads((work / "reruns.json").read_text())["header"]
    assert header["metric_settings"]["tail_time"] == 1.0  # rescored with the dataset's settings


def test_farthest_points_keep_the_sets_already_rerun():
    """A grown dataset must not discard finished reruns: the kept rows come first, the rest farthest from them."""
    x = np.array([[0.0, 0.0], [1.0, 1.0], [0.5, 0.5], [0.9, 0.0], [0.1, 0.9]])
    picked = farthest_points(x, 3, seed=0, start=[2])
    assert picked[0] == 2 and len(set(picked)) == 3
    assert picked[1] in (0, 1)  # the corners are farthest from the centre
    assert farthest_points(x, 2, seed=5, start=[3, 4]) == [3, 4]
