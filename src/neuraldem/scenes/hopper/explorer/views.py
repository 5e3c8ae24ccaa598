"""What the hopper page draws, as plain values: the numbers table (HTML) and the two Plotly figures.

No web-server code here, so the tests read the same table the browser shows. Every number cell carries its
full-precision value in `data-*` attributes beside the text `neuraldem predict` prints for it.
"""

from __future__ import annotations

import html
from typing import Any

import numpy as np

from neuraldem.scenes.hopper.explorer.stored_runs import NearRun
from neuraldem.scenes.hopper.predict import format_value
from neuraldem.scenes.hopper.whatif import QUANTITIES
from neuraldem.serve import markup
from neuraldem.serve.markup import exact

LAYER_COLOURS = ["#313695", "#4575b4", "#74add1", "#abd9e9", "#fee090", "#fdae61", "#f46d43", "#a50026"]
STORED_COLOUR = "rgba(40, 40, 40, 0.55)"


def point_text(values: dict[str, float]) -> str:
    return " ".join(f"{k}={v:g}" for k, v in values.items())


def label(key: str) -> str:
    name, unit, _ = QUANTITIES[key]
    return f"{name}{f' [{unit}]' if unit else ''}"


def numbers_table(values: dict[str, float], gp: dict[str, Any], field: dict[str, Any] | None,
                  stored: NearRun | None, field_state: str) -> str:
    """The answer side by side: GP with its 95 % interval, the field model (or its state while it computes),
    and the near stored LIGGGHTS run when there is one."""
    head = ["quantity", "GP [95 % interval]", "field model"] + ([f"LIGGGHTS {stored.sim_id}"] if stored else [])
    rows = [f"<tr>{''.join(f'<th>{html.escape(h)}</th>' for h in head)}</tr>"]
    for key in QUANTITIES:
        m, lo, hi = gp["mean"][key], gp["low"][key], gp["high"][key]
        v = None if field is None else field["summary"][key]
        cells = [f"<td>{html.escape(label(key))}</td>",
                 markup.gp_cell(m, lo, hi, f"{format_value(key, m)} [{format_value(key, lo)}, "
                                           f"{format_value(key, hi)}]"),
                 markup.field_cell(v, "" if v is None else format_value(key, v), field_state)]
        if stored is not None:
            v = stored.metrics.get(key, float("nan"))
            cells.append(f'<td class="stored" data-value="{exact(v)}">{format_value(key, v)}</td>')
        rows.append(f'<tr data-key="{key}">{"".join(cells)}</tr>')
    regimes = [gp["regime"], field["regime"] if field is not None else field_state]
    if stored is not None:
        index = stored.metrics.get("mass_flow_index", float("nan"))
        regimes.append(f"{'mass' if stored.metrics.get('mass_flow') else 'funnel'} ({index:.2f})")
    rows.append('<tr data-key="regime"><td>flow regime</td>' + "".join(
        f'<td class="{c}">{html.escape(r)}</td>' for c, r in zip(("gp", "field", "stored"), regimes, strict=False))
        + "</tr>")
    times = [f"{1000 * gp['seconds']:.1f} ms", f"{field['seconds']:.2f} s" if field is not None else ""]
    rows.append("<tr><td>answer time</td>" + "".join(f"<td>{t}</td>" for t in times) + "</tr>")
    return (f'<table id="hopper-numbers" class="nd-numbers" data-point="{html.escape(point_text(values))}">'
            + "".join(rows) + "</table>")


def held_out_line(test_errors: dict[str, Any]) -> str:
    """How far to trust the answers: the model's measured errors on its held-out LIGGGHTS runs."""
    if not test_errors.get("n_test_runs"):
        return ""
    parts = [f"{who} t95 {e['drainage_t95_pct_of_mean']:.1f} %, outflow {e['outflow_rel_err_pct']:.1f} %, "
             f"residual {e['residual_mae_pp']:.2f} pp, regime {100 * e['flow_regime_accuracy']:.0f} % right"
             for who, e in (("GP", test_errors.get("gp")), ("field model", test_errors.get("field model"))) if e]
    return f"measured on {test_errors['n_test_runs']} held-out LIGGGHTS runs: " + "; ".join(parts)


def notes_html(notes: list[str]) -> str:
    return markup.notes_html(notes, "hopper-notes")


def particles_figure(frame: Any, colour_by: str, n_layers: int, box_lo: np.ndarray, box_hi: np.ndarray,
                     title: str, residence_max: float, stored: tuple[str, np.ndarray] | None = None) -> dict[str, Any]:
    """The particles at one time, coloured by initial layer or by residence time; a stored run's in grey.
    A plain Plotly figure dict: building it skips plotly's validation, tens of milliseconds per frame."""
    p = frame.positions.astype(np.float32)  # half the bytes to the browser; far below the lattice spacing
    if colour_by == "layer":
        scale = [[(i + j) / n_layers, LAYER_COLOURS[i * len(LAYER_COLOURS) // n_layers]]
                 for i in range(n_layers) for j in (0, 1)]
        marker = {"size": 2.5, "color": frame.layer, "colorscale": scale, "cmin": -0.5, "cmax": n_layers - 0.5,
                  "colorbar": {"title": {"text": "layer"}, "tickvals": [0, n_layers - 1], "len": 0.6,
                               "ticktext": ["bottom", "top"]}}
    else:
        marker = {"size": 2.5, "color": frame.residence.astype(np.float32), "colorscale": "Viridis", "cmin": 0.0,
                  "cmax": residence_max, "colorbar": {"title": {"text": "residence [s]"}, "len": 0.6}}
    traces = [{"type": "scatter3d", "x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "mode": "markers", "marker": marker,
               "name": f"field model ({len(p)} shown)", "hoverinfo": "skip"}]
    if stored is not None:
        name, q = stored[0], stored[1].astype(np.float32)
        traces.append({"type": "scatter3d", "x": q[:, 0], "y": q[:, 1], "z": q[:, 2], "mode": "markers",
                       "name": name, "hoverinfo": "skip", "marker": {"size": 1.5, "color": STORED_COLOUR}})
    span = np.asarray(box_hi) - np.asarray(box_lo)
    axes = {f"{a}axis": {"range": [float(box_lo[i]), float(box_hi[i])], "title": {"text": f"{a} [m]"}}
            for i, a in enumerate("xyz")}
    scene = {"aspectmode": "manual", **axes, "camera": {"eye": {"x": 1.5, "y": 1.5, "z": 0.6}},
             "aspectratio": {"x": 1.0, "y": float(span[1] / span[0]), "z": float(span[2] / span[0])}}
    layout = {"title": {"text": title, "font": {"size": 13}}, "uirevision": "hopper", "height": 520,
              "margin": {"l": 0, "r": 0, "t": 36, "b": 0}, "showlegend": True,
              "legend": {"x": 0, "y": 0.02, "font": {"size": 10}}, "scene": scene}
    return {"data": traces, "layout": layout}


def discharge_figure(sketch: tuple[np.ndarray, np.ndarray], t95_interval: tuple[float, float],
                     field: tuple[np.ndarray, np.ndarray] | None, stored: tuple[str, np.ndarray, np.ndarray] | None,
                     t_now: float, t_max: float) -> dict[str, Any]:
    """Material left in the hopper over time: the GP's sketch and t95 interval at once, the field model's
    curve when computed, a near stored run's curve, and the time shown (a plain Plotly figure dict)."""
    def line(x: np.ndarray, y: np.ndarray, name: str, **style: Any) -> dict[str, Any]:
        return {"type": "scatter", "x": np.asarray(x), "y": 100 * np.asarray(y), "name": name, "mode": "lines",
                "line": style}

    traces = [line(*sketch, "GP sketch (t95, outflow, residual)", dash="dash", color="#1f77b4")]
    if field is not None:
        traces.append(line(*field, "field model", color="#d62728"))
    if stored is not None:
        traces.append(line(stored[1], stored[2], stored[0], color="#333", width=1))
    shapes = [{"type": "line", "x0": t_now, "x1": t_now, "y0": 0, "y1": 1, "yref": "paper",
               "line": {"color": "#888", "width": 1}}]
    lo, hi = t95_interval
    if np.isfinite(lo) and np.isfinite(hi):
        shapes.append({"type": "rect", "x0": lo, "x1": hi, "y0": 0, "y1": 1, "yref": "paper", "line": {"width": 0},
                       "fillcolor": "rgba(31, 119, 180, 0.15)", "layer": "below"})
    layout = {"height": 260, "margin": {"l": 50, "r": 10, "t": 30, "b": 40}, "uirevision": "curve", "shapes": shapes,
              "title": {"text": "material left in the hopper (shaded: GP t95 95 % interval)", "font": {"size": 12}},
              "xaxis": {"title": {"text": "t [s]"}, "range": [0, t_max]},
              "yaxis": {"title": {"text": "%"}, "range": [-2, 102]},
              "legend": {"x": 0.55, "y": 0.98, "font": {"size": 10}}}
    return {"data": traces, "layout": layout}
