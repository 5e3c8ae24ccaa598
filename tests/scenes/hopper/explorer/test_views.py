"""What the hopper page draws: the numbers table carries `predict`'s text and the exact values, the particle
figure colours by layer or residence time and adds a stored run as a second trace, the curve has its parts."""

from __future__ import annotations

import numpy as np

from neuraldem.scenes.hopper.explorer.engine import Frame
from neuraldem.scenes.hopper.explorer.stored_runs import NearRun
from neuraldem.scenes.hopper.explorer.views import discharge_figure, notes_html, numbers_table, particles_figure

MEAN = {"drainage_t95": 2.37, "drainage_time": 2.56, "residual_fraction": 0.0, "outflow_rate": 0.4186,
        "mass_flow_index": 0.9668}
GP = {"mean": MEAN, "low": {k: v * 0.9 for k, v in MEAN.items()}, "high": {k: v * 1.1 for k, v in MEAN.items()},
      "regime": "mass (0.97 [0.87, 1.06])", "seconds": 0.003}


def test_the_numbers_table_has_predicts_text_and_exact_values():
    run = NearRun("sim_0148", {"alpha": 39.9}, {**MEAN, "mass_flow": 1.0}, 0.01)
    table = numbers_table({"alpha": 40.0, "mu_s": 0.3}, GP, None, run, "computing ...")
    assert 'data-point="alpha=40 mu_s=0.3"' in table and "<th>LIGGGHTS sim_0148</th>" in table
    assert 'data-mean="0.4186"' in table and ">41.86 [37.67, 46.05]<" in table  # outflow in %/s, as predict
    assert table.count('class="field pending">computing ...') == 5 and "mass (0.97 [0.87, 1.06])" in table
    field = {"summary": MEAN, "regime": "mass (0.97)", "seconds": 5.3}
    assert 'class="field" data-value="2.37">2.37<' in numbers_table({"alpha": 40.0}, GP, field, None, "")


def test_clamp_notes_and_warnings_stand_out():
    html = notes_html(["alpha=99 is outside what the solver can run (0 .. 75): clamped to 75",
                       "warning: GP: alpha=75 is outside the trained range", "stored run shown: x"])
    assert html.count('class="warn"') == 2 and html.count('class="info"') == 1


def test_particles_by_layer_or_residence_with_a_stored_run():
    frame = Frame(1.0, np.random.default_rng(0).random((10, 3)), np.arange(10) % 8, np.linspace(0, 3, 10), 0.01)
    lo, hi = np.zeros(3), np.ones(3)
    by_layer = particles_figure(frame, "layer", 8, lo, hi, "alpha=40, t = 1.00 s", 4.0)
    assert len(by_layer["data"]) == 1 and by_layer["data"][0]["marker"]["cmax"] == 7.5
    stored = ("sim_0148 (LIGGGHTS, t = 1.00 s)", np.ones((5, 3)))
    by_residence = particles_figure(frame, "residence", 8, lo, hi, "alpha=40, t = 1.00 s", 4.0, stored)
    assert by_residence["data"][0]["marker"]["colorscale"] == "Viridis" and len(by_residence["data"]) == 2
    assert by_residence["layout"]["title"]["text"].startswith("alpha=40,")


def test_the_curve_has_sketch_interval_field_stored_and_time():
    t = np.linspace(0, 5, 6)
    fig = discharge_figure((t, 1 - t / 5), (2.0, 2.8), (t, 1 - t / 6), ("sim_0148", t, 1 - t / 4), 1.0, 8.0)
    assert [d["name"] for d in fig["data"]] == ["GP sketch (t95, outflow, residual)", "field model", "sim_0148"]
    assert {s["type"] for s in fig["layout"]["shapes"]} == {"line", "rect"}
    assert fig["layout"]["xaxis"]["range"] == [0, 8.0]
