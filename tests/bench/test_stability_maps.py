"""The hopper stability map: the field checks on hand-made answers with known failure times, and the whole map
on the real tiny LIGGGHTS dataset (the stored runs must pass the rule they control)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neuraldem.bench import stability_maps as hopper_stability
from neuraldem.bench.__main__ import main as bench_main
from neuraldem.bench.stability_maps import field_check
from neuraldem.errors import ConfigError
from neuraldem.scenes.hopper.surrogate.predictors import TrajectoryFields
from tests.helpers import train_tiny_gns

LO, HI = np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 2.0])


def fields(occupied_share: list[float], n: int = 100, outside: dict[int, int] | None = None) -> TrajectoryFields:
    """Occupancy with the given occupied share per time (the first points occupied), transport inside the box
    except `outside[t]` occupied points at time t."""
    t = len(occupied_share)
    occ = np.zeros((t, n))
    for k, share in enumerate(occupied_share):
        occ[k, :round(share * n)] = 1.0
    transport = np.zeros((t, n, 3)) + [0.0, 0.0, 1.0]
    for k, m in (outside or {}).items():
        transport[k, :m, 0] = 5.0
    return TrajectoryFields(np.arange(t) * 0.5, occ, transport, np.zeros((t, n)))


def test_a_draining_answer_is_stable():
    r = field_check(fields([1.0, 0.9, 0.7, 0.5, 0.5]), LO, HI, 0.1, 5.0)
    assert not r["failed"] and r["stable_time_s"] == 2.0 and r["max_rise_pct"] == 0.0


def test_material_appearing_fails_at_its_time():
    r = field_check(fields([1.0, 0.8, 0.6, 0.7, 0.5]), LO, HI, 0.1, 5.0)  # +10 % of the fill at t = 1.5 s
    assert r["failed"] and r["failed_at_time_s"] == 1.5 and "created" in r["failure"]
    assert r["max_rise_pct"] == pytest.approx(10.0)
    assert not field_check(fields([1.0, 0.8, 0.6, 0.63, 0.5]), LO, HI, 0.1, 5.0)["failed"]  # 3 % is noise


def test_a_wrong_initial_fill_fails_at_zero():
    r = field_check(fields([0.8, 0.8, 0.5]), LO, HI, 0.1, 5.0)
    assert r["failed"] and r["failed_at_time_s"] == 0.0 and "initial fill" in r["failure"]


def test_transport_outside_the_hopper_fails():
    r = field_check(fields([1.0, 1.0, 0.9], outside={2: 20}), LO, HI, 0.1, 5.0)
    assert r["failed"] and r["failed_at_time_s"] == 1.0 and "outside" in r["failure"]
    assert r["max_outside_pct"] == pytest.approx(20.0)
    # the earliest problem is the one reported
    r = field_check(fields([1.0, 1.0, 1.2], outside={1: 20}), LO, HI, 0.1, 5.0)
    assert r["failed_at_time_s"] == 0.5


@pytest.mark.solver
def test_map_on_the_tiny_dataset(tiny_checkpoint: Path, hopper_tiny_dataset: Path, tmp_path: Path):
    gns = train_tiny_gns(hopper_tiny_dataset, "hopper_tiny", tmp_path / "gns.ckpt")
    res = hopper_stability.run([tiny_checkpoint], [gns], ["field", "gns"], n_sims=2, mu_s=[0.5, 3.0],
                               gns_steps=3, dataset_dir=hopper_tiny_dataset)
    truth, field, graph = res["series"]
    assert truth["method"] == "solver" and not any(p["failed"] for p in truth["points"]), truth["points"]
    n = len(res["sims"])
    assert len(field["points"]) == len(graph["points"]) == 2 * n
    assert [p["inside_range"] for p in field["points"][:2]] == [True, False]  # 3.0 is beyond the trained range
    for p in field["points"] + graph["points"]:
        assert 0 <= p["stable_time_s"] <= p["time_s"] and (p["failed"] == bool(p["failure"]))
    assert all(p["steps"] == 3 for p in graph["points"])
    out = tmp_path / "hs.json"
    assert bench_main(["hopper_stability", f"ckpt=[{tiny_checkpoint}]", "sims=1", "mu_s=[0.5]",
                       f"dataset={hopper_tiny_dataset}", f"out={out}"]) == 0
    md = out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").is_file() and "| LIGGGHTS (stored run) |" in md and "| tiny |" in md


def test_bad_options_are_refused(tiny_checkpoint: Path):
    with pytest.raises(ConfigError, match="labels=: 2 label"):
        hopper_stability.run([tiny_checkpoint], [], ["a", "b"])
    with pytest.raises(ConfigError, match=r"config value sims=0 is invalid.*e\.g\. sims=\.\.\."):
        hopper_stability.run([tiny_checkpoint], n_sims=0)
    with pytest.raises(ConfigError, match="ckpt= is required"):
        hopper_stability.run([])
