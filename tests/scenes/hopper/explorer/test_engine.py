"""The explorer's answers, without a browser: the numbers are `neuraldem predict hopper fields=false`'s, the whole
discharge is `neuraldem predict`'s field answer, frames are drawable and cached, the GP sketch is a curve."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import TINY

POINT = {"alpha": 30.0, "mu_s": 0.4, "mu_r": 0.2}


def predict_json(capsys, tmp_path: Path, point: dict[str, float], *options: str) -> dict:
    from neuraldem import predict

    assert predict.main(["hopper", *(f"{k}={v:g}" for k, v in point.items()), f"model={TINY}", "json=true",
                         f"out={tmp_path}", *options]) == 0
    return json.loads(capsys.readouterr().out)


def test_the_numbers_are_predicts_gp_answer(tiny_engine, use_tiny_model, capsys, tmp_path: Path):
    printed = predict_json(capsys, tmp_path, POINT, "fields=false")["gp"]
    shown = tiny_engine.numbers(tiny_engine.point(POINT))
    for part in ("mean", "low", "high"):
        assert shown[part] == printed[part], part
    assert shown["regime"] == printed["regime"] and not shown["warnings"]


def test_the_whole_discharge_is_predicts_field_answer(tiny_engine, use_tiny_model, capsys, tmp_path: Path):
    printed = predict_json(capsys, tmp_path, POINT, "pictures=false")["field"]
    done = tiny_engine.compute_discharge(tiny_engine.point(POINT))
    assert done.answer["n_points"] == printed["n_points"] and done.answer["regime"] == printed["regime"]
    for key, value in printed["summary"].items():  # the same calls: the same numbers, to the last bit
        assert done.answer["summary"][key] == pytest.approx(value, rel=0, abs=0, nan_ok=True), key
    assert len(done.remaining) == len(tiny_engine.times) and np.all((done.remaining >= 0) & (done.remaining <= 1))
    assert tiny_engine.discharge(tiny_engine.point(POINT)) is done  # cached


def test_a_discharge_nobody_wants_stops(tiny_engine):
    point = tiny_engine.point({**POINT, "alpha": 31.0})
    assert tiny_engine.compute_discharge(point, cancelled=lambda: True) is None
    assert tiny_engine.discharge(point) is None


def test_a_frame_is_drawable_and_cached(tiny_engine):
    point = tiny_engine.point(POINT)
    frame = tiny_engine.frame(point, 3)
    lo, hi = np.asarray(tiny_engine.norm.box_lo), np.asarray(tiny_engine.norm.box_hi)
    assert len(frame.positions) > 0 and np.all((frame.positions >= lo - 1e-9) & (frame.positions <= hi + 1e-9))
    assert frame.layer.min() >= 0 and frame.layer.max() < tiny_engine.settings.n_layers
    assert np.all(frame.residence >= 0) and frame.time == pytest.approx(tiny_engine.times[3])
    assert tiny_engine.frame(point, 3) is frame
    assert len(tiny_engine.drawn(point).points) <= len(tiny_engine.material(point).points)


def test_the_gp_sketch_runs_from_full_to_the_residual():
    from neuraldem.scenes.hopper.explorer.engine import gp_discharge_sketch

    mean = {"drainage_t95": 2.4, "drainage_time": 2.6, "residual_fraction": 0.1, "outflow_rate": 0.4}
    t, level = gp_discharge_sketch(mean, horizon=15.0)
    assert t[0] == 0 and level[0] == 1 and t[-1] == 15 and level[-1] == pytest.approx(0.1)
    assert np.all(np.diff(t) > 0) and np.all(np.diff(level) <= 0)
    assert np.interp(2.4, t, level) == pytest.approx(1 - 0.95 * 0.9)  # t95: 95 % of the discharged share left
    flat_t, flat = gp_discharge_sketch({**mean, "outflow_rate": float("nan")}, horizon=15.0)
    assert list(flat) == [1.0, 1.0] and list(flat_t) == [0.0, 15.0]
