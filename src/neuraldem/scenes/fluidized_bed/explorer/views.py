"""What the bed page draws, as plain values: the numbers table, the held-out errors (HTML) and the two Plotly
figures (solid fraction and mixing on the central slice; bed height, bubble fraction and Lacey curves).

No web-server code here, so the tests read the same table the browser shows. Every number cell carries its
full-precision value in `data-*` attributes beside the text `neuraldem predict fb` prints for it.
"""

from __future__ import annotations

import html
from typing import Any

import numpy as np

from neuraldem.scenes.fluidized_bed.whatif import answer_label as label  # predict fb's labels and values
from neuraldem.scenes.fluidized_bed.whatif import format_answer as shown
from neuraldem.serve import markup
from neuraldem.serve.markup import exact

SOLID_MAX = 0.65  # colour range of the solid fraction (plots.animate_fields)
GP_COLOUR, FIELD_COLOUR = "#1f77b4", "#d62728"
ERROR_ROWS = (("GP", "gp"), ("field model", "field model"), ("training mean", "constant"),
              ("CFD-DEM from another packing", "seed floor"))


def velocity_text(v: float) -> str:
    return f"{v:g} m/s"


def numbers_table(velocity: float, gp: dict[str, Any], field: Any | None, field_state: str,
                  quantities: dict[str, tuple[str, str, float]]) -> str:
    """GP with its 95 % interval, and the field model's answer from the rollout at exactly this velocity (or
    its state while it computes)."""
    rows = ["<tr><th>quantity</th><th>GP [95 % interval]</th><th>field model (rollout)</th></tr>"]
    for key in quantities:
        m, lo, hi = gp["mean"][key], gp["low"][key], gp["high"][key]
        v = None if field is None else field.summary[key]
        cells = [f"<td>{html.escape(label(key, quantities))}</td>",
                 markup.gp_cell(m, lo, hi, f"{shown(key, m, quantities)} [{shown(key, lo, quantities)}, "
                                           f"{shown(key, hi, quantities)}]"),
                 markup.field_cell(v, shown(key, v, quantities), field_state)]
        rows.append(f'<tr data-key="{key}">{"".join(cells)}</tr>')
    times = [f"{1000 * gp['seconds']:.1f} ms", f"{field.seconds:.1f} s" if field is not None else ""]
    rows.append("<tr><td>answer time</td>" + "".join(f"<td>{t}</td>" for t in times) + "</tr>")
    return (f'<table id="bed-numbers" class="nd-numbers" data-velocity="{exact(velocity)}">'
            + "".join(rows) + "</table>")


def held_out_table(test_errors: dict[str, Any]) -> str:
    """How far to trust each answer: mean absolute errors on the held-out CFD-DEM runs (meta.json), beside
    CFD-DEM's own spread (the same velocity from another packing) and the training mean."""
    if not test_errors.get("n_test_runs"):
        return ""
    rows = ["<tr><th>mean abs. error</th><th>bed height</th><th>bubble fraction</th><th>Lacey</th></tr>"]
    for name, key in ERROR_ROWS:
        e = test_errors.get(key)
        if e:
            rows.append(f'<tr data-key="{html.escape(key)}"><td>{name}</td><td>{e["bed_height_mae_mm"]:.2f} mm</td>'
                        f'<td>{e["bubble_fraction_mae_pp"]:.2f} pp</td><td>{e["lacey_mae"]:.3f}</td></tr>')
    return (f'<table id="bed-errors" class="nd-numbers"><caption>on {test_errors["n_test_runs"]} held-out '
            "CFD-DEM runs (meta.json): an answer near CFD-DEM's own spread is as good as rerunning CFD-DEM"
            "</caption>" + "".join(rows) + "</table>")


def notes_html(notes: list[str]) -> str:
    return markup.notes_html(notes, "bed-notes")


def fields_title(velocity: float, r: Any | None, t: float | None) -> str:
    """The title the fields figure carries (the browser probe waits for its prefix)."""
    head = f"inlet velocity {velocity_text(velocity)}:"
    if r is None:
        return f"{head} no rollout ready yet (the first ones are computing)"
    which = "exact" if r.velocity == velocity else "nearest ready; the exact one computes once the slider rests"
    return f"{head} rollout at {velocity_text(r.velocity)} ({which}), t = {t:.2f} s"


def fields_figure(velocity: float, r: Any | None, state: int, x: np.ndarray, z: np.ndarray) -> dict[str, Any]:
    """Solid fraction and mixing on the central y slice at one rollout state (heatmaps, z up), a plain Plotly
    figure dict; the mixing is blank where there is (almost) no solid."""
    t = float(r.times[state]) if r is not None else None
    layout = {"title": {"text": fields_title(velocity, r, t), "font": {"size": 12}}, "height": 470,
              "margin": {"l": 50, "r": 10, "t": 40, "b": 40}, "uirevision": "bed-fields",
              "xaxis": {"domain": [0.0, 0.40], "title": {"text": "x [mm]"}, "constrain": "domain"},
              "yaxis": {"title": {"text": "z [mm]"}, "scaleanchor": "x"},
              "xaxis2": {"domain": [0.55, 0.95], "title": {"text": "x [mm]"}, "constrain": "domain"},
              "yaxis2": {"anchor": "x2", "scaleanchor": "x2", "matches": "y"},
              "annotations": [{"text": "solid fraction", "x": 0.2, "xref": "paper", "y": 1.0, "yref": "paper",
                               "showarrow": False, "yanchor": "bottom"},
                              {"text": "mixing (0 started left, 1 right)", "x": 0.75, "xref": "paper", "y": 1.0,
                               "yref": "paper", "showarrow": False, "yanchor": "bottom"}]}
    if r is None:
        return {"data": [], "layout": layout}
    common = {"type": "heatmap", "x": x.astype(np.float32), "y": z.astype(np.float32), "hoverongaps": False}
    data = [{**common, "z": r.solid_fraction[state].T, "colorscale": "Viridis", "zmin": 0.0, "zmax": SOLID_MAX,
             "colorbar": {"x": 0.41, "len": 0.8, "thickness": 12}, "name": "solid fraction"},
            {**common, "z": r.mixing[state].T, "colorscale": "RdBu", "reversescale": True, "zmin": 0.0, "zmax": 1.0,
             "xaxis": "x2", "yaxis": "y2", "colorbar": {"x": 0.96, "len": 0.8, "thickness": 12}, "name": "mixing"}]
    return {"data": data, "layout": layout}


def curves_figure(velocity: float, gp: dict[str, Any], r: Any | None, t: float | None,
                  quantities: dict[str, tuple[str, str, float]], lacey_time: float) -> dict[str, Any]:
    """Bed height, bubble fraction and Lacey index over time from the shown rollout, the GP's answers (time
    means, and Lacey at `lacey_time`) with their 95 % intervals, and a line at the time shown."""
    keys = ("bed_height", "bubble_fraction", "lacey")
    domains = ((0.70, 1.0), (0.36, 0.64), (0.0, 0.30))
    data, shapes = [], []
    for i, key in enumerate(keys):
        axis = "" if i == 0 else str(i + 1)
        scale = quantities[key][2]
        if r is not None:
            curve = getattr(r.curves, key)
            data.append({"type": "scatter", "x": r.curves.times, "y": scale * np.asarray(curve), "mode": "lines",
                         "line": {"color": FIELD_COLOUR, "width": 1.5}, "xaxis": f"x{axis}", "yaxis": f"y{axis}",
                         "name": f"rollout at {velocity_text(r.velocity)}", "showlegend": i == 0})
        m, lo, hi = (scale * gp[p][key] for p in ("mean", "low", "high"))
        gp_name = "GP (time mean)" if key != "lacey" else f"GP (at {lacey_time:g} s)"
        if key == "lacey":
            data.append({"type": "scatter", "x": [lacey_time], "y": [m], "mode": "markers", "xaxis": f"x{axis}",
                         "yaxis": f"y{axis}", "marker": {"color": GP_COLOUR, "size": 8}, "name": gp_name,
                         "error_y": {"type": "data", "symmetric": False, "array": [hi - m], "arrayminus": [m - lo]},
                         "showlegend": False})
        elif np.isfinite(m):
            shapes.append({"type": "rect", "xref": f"x{axis} domain", "yref": f"y{axis}", "x0": 0, "x1": 1,
                           "y0": lo, "y1": hi, "fillcolor": "rgba(31, 119, 180, 0.15)", "line": {"width": 0},
                           "layer": "below"})
            shapes.append({"type": "line", "xref": f"x{axis} domain", "yref": f"y{axis}", "x0": 0, "x1": 1,
                           "y0": m, "y1": m, "line": {"color": GP_COLOUR, "dash": "dash", "width": 1}})
        if t is not None:
            shapes.append({"type": "line", "xref": f"x{axis}", "yref": f"y{axis} domain", "x0": t, "x1": t, "y0": 0,
                           "y1": 1, "line": {"color": "#888", "width": 1}})
    layout = {"height": 380, "margin": {"l": 60, "r": 10, "t": 40, "b": 35}, "uirevision": "bed-curves",
              "shapes": shapes, "showlegend": True, "legend": {"x": 0.45, "y": 1.0, "yanchor": "bottom",
                                                               "orientation": "h", "font": {"size": 10}},
              "title": {"text": "dashed / shaded: GP answer and 95 % interval", "font": {"size": 11}, "x": 0.02}}
    for i, key in enumerate(keys):
        axis = "" if i == 0 else str(i + 1)
        layout[f"xaxis{axis}"] = {"anchor": f"y{axis}", "showticklabels": i == 2,
                                  **({"title": {"text": "t [s]"}} if i == 2 else {"matches": "x3"})}
        unit = quantities[key][1]
        layout[f"yaxis{axis}"] = {"domain": list(domains[i]), "anchor": f"x{axis}",
                                  "title": {"text": key.replace("_", " ") + (f" [{unit}]" if unit else ""),
                                            "font": {"size": 10}}}
    return {"data": data, "layout": layout}
