"""The bed page end to end: `neuraldem serve page=bed` on a free localhost port with the tiny bed model, in a
real headless Chromium driven with the keyboard. A slider move changes the numbers to `neuraldem predict
fluidized_bed`'s for the new velocity (GP at once, the field model's when the exact rollout is done), the fields
show the nearest ready rollout at once and then the exact one; typed values beyond the solver's limits are clamped with
a visible note; the time slider moves the fields. Screenshots go to each test's tmp_path."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.serve.browser import chromium_paths
from tests.scenes.fluidized_bed.explorer.test_engine import FB_TINY, predict_fb_json

pytestmark = pytest.mark.skipif(chromium_paths() is None, reason="needs Debian's chromium and chromium-driver "
                                "(apt-get install chromium chromium-driver; scripts/setup.sh installs them)")


@pytest.fixture(scope="module")
def bed(fb_tiny_pretrained: Path):
    from neuraldem.scenes.fluidized_bed.explorer.browser import BedBrowser, page_url
    from neuraldem.serve.browser import ServerProcess, start_chromium

    env = {"NEURALDEM_PRETRAINED_DIR": str(fb_tiny_pretrained)}
    with ServerProcess([f"model={FB_TINY}", "page=bed"], env=env) as server:
        driver = start_chromium()
        try:
            yield BedBrowser(driver, page_url(server.url), timeout=90)
        finally:
            driver.quit()


@pytest.fixture
def use_fb_tiny(fb_tiny_pretrained: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NEURALDEM_PRETRAINED_DIR", str(fb_tiny_pretrained))


def test_a_slider_move_shows_predicts_numbers_then_the_exact_rollout(bed, use_fb_tiny, capsys, tmp_path: Path):
    from neuraldem.scenes.fluidized_bed.explorer.views import shown
    from neuraldem.scenes.fluidized_bed.whatif import quantities
    from neuraldem.serve.inputs import parameter_value

    before = bed.numbers()
    bed.press("right")
    after = bed.wait_numbers_for(parameter_value(before["velocity"] + 0.01))
    v = after["velocity"]
    assert v == parameter_value(before["velocity"] + 0.01) and after["gp"] != before["gp"]
    printed = predict_fb_json(capsys, tmp_path, v)
    q = quantities(printed["answer_window"]["lacey_time"])
    gp = printed["gp"]
    for key, (mean, low, high) in after["gp"].items():
        assert (mean, low, high) == (gp["mean"][key], gp["low"][key], gp["high"][key]), key
        assert after["text"][key][0] == f"{shown(key, mean, q)} [{shown(key, low, q)}, {shown(key, high, q)}]"
    # the exact rollout once the slider rests: the field model's numbers are predict's, the fields its own
    done = bed.wait_field_numbers(v, timeout=90)
    assert done["field"] == printed["field"]["summary"]
    assert all(done["text"][k][1] == shown(k, printed["field"]["summary"][k], q) for k in q)
    from neuraldem.serve.browser import wait_for

    title = bed.wait_shown(v)
    # the status line is another element, updated in the same draw: it may reach the DOM a moment after the title
    wait_for(lambda: bed.status("shown") == repr(v), 30, f"the status naming the rollout at {v:g} m/s")
    assert "(exact)" in title
    bed.screenshot(tmp_path / "exact_rollout.png")


def test_a_move_shows_the_nearest_ready_rollout_at_once(bed, tmp_path: Path):
    from neuraldem.serve.browser import wait_for

    lattice = int(bed.status("lattice"))
    wait_for(lambda: bed.status("ready") == str(lattice), 120, "the lattice rollouts")
    v = float(bed.status("velocity"))
    target = round(v + 0.01, 6)
    timed = bed.timed_press(target)
    assert timed["numbers_ms"] > 0 and timed["fields_ms"] > 0
    # the figure drawn for the new velocity names the rollout it shows: the exact one, or the nearest ready
    assert timed["fields_title"].startswith(f"inlet velocity {target:g} m/s: rollout at ")
    shown = float(timed["fields_title"].split("rollout at ")[1].split(" m/s")[0])
    assert shown == target or "(nearest ready" in timed["fields_title"]
    bed.screenshot(tmp_path / "nearest.png")


def test_typed_values_beyond_the_solver_are_clamped_with_a_note(bed, tmp_path: Path):
    bed.type_value("25")
    bed.wait_numbers_for(20.0)
    notes = bed.notes()
    assert "inlet_velocity=25 is outside what the solver can run (0 .. 20): clamped to 20" in notes
    assert any(n.startswith("warning: GP: inlet_velocity=20 is outside the trained range") for n in notes)
    assert bed.within(".nd-typed-inlet_velocity", "input").get_attribute("value") == "20"
    bed.screenshot(tmp_path / "clamped.png")
    bed.type_value("fast")
    from neuraldem.serve.browser import wait_for

    wait_for(lambda: "inlet_velocity: 'fast' is not a number; the previous value is kept" in bed.notes(), 30,
             "the not-a-number note")
    assert bed.numbers()["velocity"] == 20.0


def test_the_time_slider_moves_the_fields(bed, tmp_path: Path):
    from neuraldem.serve.browser import wait_for

    before_t, before_title = bed.status("time"), bed.fields_title()
    at_end = int(bed.status("frame")) == int(bed.status("frames")) - 1
    bed.press_time("left" if at_end else "right")
    wait_for(lambda: bed.status("time") != before_t, 30, "the next time")
    after_title = wait_for(lambda: (t := bed.fields_title()) != before_title and t, 30, "the fields redrawn")
    assert f"t = {float(bed.status('time')):.2f} s" in after_title
    assert json.loads(bed.driver.execute_script("return JSON.stringify(window.ndBedFields().data.length);")) == 2
