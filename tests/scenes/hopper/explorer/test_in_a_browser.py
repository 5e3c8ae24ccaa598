"""`neuraldem serve` end to end: the server on a free localhost port, the hopper page in a real headless
Chromium, driven with the keyboard. A slider move changes the numbers to `neuraldem predict`'s for the new
point (GP at once, field model when its whole discharge is done); typed values beyond the solver's limits are
clamped with a visible note; a stored LIGGGHTS run at the point is shown beside the model; the time slider
moves the particles. Screenshots go to each test's tmp_path."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.serve.browser import chromium_paths
from tests.conftest import TINY

pytestmark = pytest.mark.skipif(chromium_paths() is None, reason="needs Debian's chromium and chromium-driver "
                                "(apt-get install chromium chromium-driver; scripts/setup.sh installs them)")


@pytest.fixture(scope="module")
def page(tiny_pretrained: Path, data_root: Path, hopper_tiny_dataset: Path):
    """The hopper page of the tiny model, its stored runs (the tiny dataset) in the data dir."""
    from neuraldem.scenes.hopper.explorer.browser import HopperBrowser
    from neuraldem.serve.browser import ServerProcess, start_chromium

    env = {"NEURALDEM_PRETRAINED_DIR": str(tiny_pretrained), "NEURALDEM_DATA": str(data_root)}
    with ServerProcess([f"model={TINY}"], env=env) as server:
        driver = start_chromium()
        try:
            yield HopperBrowser(driver, server.url, timeout=90)
        finally:
            driver.quit()


def parse(point: str) -> dict[str, float]:
    return {k: float(v) for k, v in (item.split("=") for item in point.split())}


def predict_json(capsys, tmp_path: Path, point: str, *options: str) -> dict:
    from neuraldem import predict

    assert predict.main(["hopper", *point.split(), f"model={TINY}", "json=true", f"out={tmp_path}", *options]) == 0
    return json.loads(capsys.readouterr().out)


def test_a_slider_move_shows_predicts_numbers_for_the_new_point(page, use_tiny_model, capsys, tmp_path: Path):
    from neuraldem.scenes.hopper.predict import format_value

    before = page.numbers()
    page.press("alpha", "right")
    after = page.wait_numbers_change(before["point"])
    moved = parse(after["point"])
    assert moved == {**parse(before["point"]), "alpha": parse(before["point"])["alpha"] + 0.5}
    assert after["gp"] != before["gp"]  # the numbers changed with the point
    gp = predict_json(capsys, tmp_path, after["point"], "fields=false")["gp"]
    for key, (mean, low, high) in after["gp"].items():
        assert [mean, low, high] == pytest.approx([gp["mean"][key], gp["low"][key], gp["high"][key]], rel=0,
                                                  abs=0, nan_ok=True), key
        shown = f"{format_value(key, gp['mean'][key])} [{format_value(key, gp['low'][key])}, " \
                f"{format_value(key, gp['high'][key])}]"
        assert after["text"][key][0] == shown, key
    assert after["regime"][0] == gp["regime"]
    page.wait_frame_for(after["point"])  # the particles follow
    page.screenshot(tmp_path / "after_slider_move.png")


def test_the_field_numbers_are_predicts_field_answer(page, use_tiny_model, capsys, tmp_path: Path):
    shown = page.wait_field_numbers(timeout=90)
    field = predict_json(capsys, tmp_path, shown["point"], "time_stride=2")["field"]
    for key, value in shown["field"].items():
        assert value == pytest.approx(field["summary"][key], rel=1e-12, nan_ok=True), key
    assert shown["regime"][1] == field["regime"]
    page.screenshot(tmp_path / "field_numbers.png")


def test_typed_values_beyond_the_solver_are_clamped_with_a_note(page, tmp_path: Path):
    expected = " ".join(f"{k}={v:g}" for k, v in {**parse(page.numbers()["point"]), "alpha": 75.0}.items())
    page.type_value("alpha", "99")
    clamped = page.wait_numbers_for(expected)
    notes = page.notes()
    assert "alpha=99 is outside what the solver can run (0 .. 75): clamped to 75" in notes
    assert any(n.startswith("warning: GP: alpha=75 is outside the trained range") for n in notes)
    assert page.within(".nd-typed-alpha", "input").get_attribute("value") == "75"
    page.screenshot(tmp_path / "clamped.png")
    page.type_value("mu_s", "abc")
    page.wait_for_note("mu_s: 'abc' is not a number; the previous value is kept")
    assert page.numbers()["point"] == clamped["point"]


def test_a_stored_run_at_the_point_is_shown_beside_the_model(page, hopper_tiny_dataset: Path, tmp_path: Path):
    manifest = json.loads((hopper_tiny_dataset / "manifest.json").read_text())
    run = next(r for r in manifest["simulations"] if r["status"] == "ok" and r["metrics"])
    for key in ("alpha", "mu_s", "mu_r"):
        page.type_value(key, f"{run['params'][key]:g}")
    point = " ".join(f"{k}={run['params'][k]:g}" for k in ("alpha", "mu_s", "mu_r"))
    shown = page.wait_numbers_for(point)
    assert shown["stored"]["drainage_t95"] == pytest.approx(run["metrics"]["drainage_t95"])
    assert any(n.startswith(f"stored run shown: LIGGGHTS {run['sim_id']}") for n in page.notes())
    page.wait_frame_for(point)
    assert page.driver.execute_script("return window.ndAll('.js-plotly-plot')[0].data.length;") == 2
    page.screenshot(tmp_path / "stored_run.png")


def test_the_time_slider_moves_the_particles(page, tmp_path: Path):
    point, t, step = page.status("point"), float(page.status("time")), float(page.status("step"))
    latency = page.timed_time_step(point, round(t + step, 9))
    assert float(page.status("time")) == pytest.approx(t + step) and latency["fields_ms"] > 0
    page.screenshot(tmp_path / "next_time.png")
