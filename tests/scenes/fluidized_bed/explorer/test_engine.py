"""The bed page's answers without a browser (the tiny shipped bed model of tests/conftest.py): the GP numbers
and the rollout's numbers are `neuraldem predict fb`'s, pauses between steps do not change a rollout, the
worker does a resting session's exact velocity before the lattice, and the views draw what they are given."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest

FB_TINY = "fb_tiny_test"


@pytest.fixture(scope="module")
def bed_engine(fb_tiny_pretrained: Path):
    from neuraldem import pretrained
    from neuraldem.scenes.fluidized_bed.explorer.engine import BedEngine

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NEURALDEM_PRETRAINED_DIR", str(fb_tiny_pretrained))
        return BedEngine(pretrained.load(FB_TINY, "fluidized_bed"), lattice=3)


def predict_fb_json(capsys, tmp_path: Path, velocity: float, *options: str) -> dict:
    from neuraldem import predict

    assert predict.main(["fluidized_bed", f"inlet_velocity={velocity:g}", f"model={FB_TINY}", "json=true",
                         f"out={tmp_path}", *options]) == 0
    return json.loads(capsys.readouterr().out)


def test_numbers_and_rollout_answers_are_predicts(bed_engine, fb_tiny_pretrained: Path, monkeypatch, capsys,
                                                  tmp_path: Path):
    monkeypatch.setenv("NEURALDEM_PRETRAINED_DIR", str(fb_tiny_pretrained))
    lo, hi = bed_engine.slider_range()
    v = bed_engine.velocity((lo + hi) / 2)
    printed = predict_fb_json(capsys, tmp_path, v)
    gp = bed_engine.numbers(v)
    for part in ("mean", "low", "high"):
        assert gp[part] == printed["gp"][part], part
    paused = []

    def gate() -> None:  # a pause before every step, as when a person moves the slider meanwhile
        paused.append(1)
        time.sleep(0.001)

    r = bed_engine.compute(v, gate)
    assert len(paused) == bed_engine.window.steps and r.velocity == v
    assert r.summary == printed["field"]["summary"] and np.isfinite(r.summary["bed_height"])
    assert r.start == printed["field"]["start"]
    assert bed_engine.rollout(v) is r and bed_engine.nearest_ready(v + 1e-3) is None  # exact only at v
    # the fields kept are the central slice, mixing blank where there is no solid
    assert r.solid_fraction.shape == (len(r.times), len(bed_engine.x_centres), len(bed_engine.z_centres))
    assert np.isnan(r.mixing[r.solid_fraction <= 0.02]).all()
    assert np.isfinite(r.mixing[r.solid_fraction > 0.02]).all()


def test_the_worker_does_a_resting_velocity_before_the_lattice(bed_engine):
    from neuraldem.scenes.fluidized_bed.explorer.engine import Superseded
    from neuraldem.scenes.fluidized_bed.explorer.worker import RolloutWorker

    worker = RolloutWorker(bed_engine, start=False)
    assert sorted(worker._lattice) == bed_engine.lattice and len(bed_engine.lattice) == 3
    assert worker.next_job() == (worker._lattice[0], False)  # nothing wanted: the lattice, middle first
    wanted = bed_engine.velocity(bed_engine.lattice[0] + 0.003)
    called = threading.Event()
    worker.want("session", wanted, called.set)
    assert worker.next_job() == (wanted, True)
    with pytest.raises(Superseded):  # a lattice rollout stops between steps while an exact one waits
        worker._gate(worker._lattice[0], exact=False)()
    worker.want("session", bed_engine.velocity(wanted + 0.001), called.set)
    with pytest.raises(Superseded):  # the session moved on: the old exact velocity is dropped
        worker._gate(wanted, exact=True)()
    worker.forget("session")
    # run it: the whole lattice, then the nearest ready rollout is a lattice one
    worker._thread.start()
    worker._wake.set()
    from neuraldem.serve.browser import wait_for

    wait_for(lambda: bed_engine.lattice_ready() == 3, 120, "the lattice rollouts")
    near = bed_engine.nearest_ready(wanted)
    assert near.velocity == bed_engine.lattice[0] and not called.is_set()


def test_the_views_show_the_numbers_and_the_shown_rollout(bed_engine):
    from neuraldem.scenes.fluidized_bed.explorer import views

    v = bed_engine.lattice[0]
    r = bed_engine.compute(v)
    gp = bed_engine.numbers(v)
    q = bed_engine.quantities
    table = views.numbers_table(v, gp, r, "", q)
    for key in q:
        assert f'data-value="{r.summary[key]!r}"' in table
        assert f"{views.shown(key, gp['low'][key], q)}, {views.shown(key, gp['high'][key], q)}]" in table
    pending = views.numbers_table(v, gp, None, "computing ...", q)
    assert "computing ..." in pending and "data-value" not in pending
    other = bed_engine.velocity(v + 0.004)
    fig = views.fields_figure(other, r, 3, bed_engine.x_centres, bed_engine.z_centres)
    assert fig["layout"]["title"]["text"].startswith(f"inlet velocity {other:g} m/s: rollout at {v:g} m/s (nearest")
    assert np.array_equal(fig["data"][0]["z"], r.solid_fraction[3].T, equal_nan=True)
    assert np.array_equal(fig["data"][1]["z"], r.mixing[3].T, equal_nan=True)
    curves = views.curves_figure(v, gp, r, float(r.times[3]), q, bed_engine.window.lacey_time)
    assert [d["name"] for d in curves["data"]][:2] == [f"rollout at {v:g} m/s"] * 2
    assert np.allclose(curves["data"][0]["y"], 1000 * r.curves.bed_height, equal_nan=True)
    assert views.fields_figure(v, None, 0, bed_engine.x_centres, bed_engine.z_centres)["data"] == []
