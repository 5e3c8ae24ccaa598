"""The hopper page: sliders for the model's inputs, a time player, the particles in 3D, the discharge curve,
the numbers with their intervals, and a stored LIGGGHTS run when one is near.

Every move updates in two steps so the cheap answer never waits for the costly one:
1. numbers (GP, milliseconds) in the widget's own callback, sent to the browser at once;
2. the shown frame and the curve on a worker thread (tens of milliseconds), applied on the session's next
   tick; a newer move supersedes an older one that has not been drawn yet.
The whole discharge (field model numbers and curve, seconds) then runs on the shared background worker.
"""

from __future__ import annotations

import html
import math
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import panel as pn

from neuraldem import pretrained
from neuraldem.scenes.hopper.explorer import views
from neuraldem.scenes.hopper.explorer.engine import HopperEngine, Point, gp_discharge_sketch
from neuraldem.scenes.hopper.explorer.stored_runs import StoredRuns
from neuraldem.scenes.hopper.explorer.worker import DischargeWorker
from neuraldem.scenes.parameters import range_warnings, ranges_line
from neuraldem.serve.inputs import parameter_value, typed_value
from neuraldem.serve.markup import CSS

SCENE_KIND = "hopper"
TITLE = "Hopper discharge"
DEFAULT_POINT = {"alpha": 40.0, "mu_s": 0.3, "mu_r": 0.1}  # `neuraldem predict`'s example
DEFAULT_TIME = 1.0  # [s] mid-discharge: the layers are already bent
STEPS = {"alpha": 0.5, "mu_s": 0.01, "mu_r": 0.005}  # slider steps (keyboard arrows move by one)
LABELS = {"alpha": "cone angle alpha [deg]", "mu_s": "sliding friction mu_s", "mu_r": "rolling friction mu_r"}
PLAY_INTERVAL_MS = 200
LEFT = 480  # width of the controls column [px]
STORED_SHOWN = 1500  # a stored run's particles drawn at most (a fixed random subset)



@dataclass
class HopperShared:
    """What every session of the hopper page shares: the loaded model, its caches, the stored runs, the
    background worker and the frame thread."""

    engine: HopperEngine
    stored: StoredRuns | None
    stored_note: str
    worker: DischargeWorker
    frames: ThreadPoolExecutor


def prepare(model_name: str | None, dataset: Path | None, near: float) -> HopperShared:
    """Load the hopper model (files verified: a missing or damaged one is a DataError) and its stored runs."""
    model = pretrained.load(model_name or pretrained.default_for(SCENE_KIND), SCENE_KIND)
    engine = HopperEngine(model)
    stored, note = StoredRuns.for_model(model.meta, dataset, near)
    return HopperShared(engine, stored, note, DischargeWorker(engine),
                        ThreadPoolExecutor(max_workers=1, thread_name_prefix="hopper-frames"))


def default_values(engine: HopperEngine) -> dict[str, float]:
    """`predict`'s example point, moved onto the sliders (inside the trained range) when the model's range is
    another: the page opens inside what the model was trained on."""
    out = {}
    for k in engine.inputs:
        lo, hi = engine.trained_range[k]
        slo, shi = slider_range(lo, hi, slider_step(engine, k))
        out[k] = parameter_value(min(max(DEFAULT_POINT.get(k, (lo + hi) / 2), slo), shi))
    return out


def slider_step(engine: HopperEngine, k: str) -> float:
    return STEPS.get(k, (engine.trained_range[k][1] - engine.trained_range[k][0]) / 100)


def slider_range(lo: float, hi: float, step: float) -> tuple[float, float]:
    """The trained range on the slider's step grid (inside it)."""
    return parameter_value(math.ceil(lo / step - 1e-9) * step), parameter_value(math.floor(hi / step + 1e-9) * step)


class HopperPage:
    """One browser session's page."""

    def __init__(self, shared: HopperShared):
        self.shared, self.engine = shared, shared.engine
        self.doc = pn.state.curdoc
        self.values = default_values(self.engine)
        self.clamp_notes: dict[str, str] = {}
        self._syncing = False
        self._field_pending = True  # the numbers table waits for the field model's whole discharge
        self._generation = 0
        self._lock = threading.Lock()
        self.sliders, self.typed = {}, {}
        for k in self.engine.inputs:
            step = slider_step(self.engine, k)
            lo, hi = slider_range(*self.engine.trained_range[k], step)
            self.sliders[k] = pn.widgets.FloatSlider(name=LABELS.get(k, k), start=lo, end=hi, step=step,
                                                     value=min(max(self.values[k], lo), hi), width=260,
                                                     css_classes=[f"nd-slider-{k}"])
            self.typed[k] = pn.widgets.TextInput(value=f"{self.values[k]:g}", width=90, css_classes=[f"nd-typed-{k}"])
            self.sliders[k].param.watch(partial(self._slid, k), "value")
            self.sliders[k].param.watch(self._schedule_fields, "value_throttled")
            self.typed[k].param.watch(partial(self._typed, k), "value")
        t0 = self.engine.time_index(DEFAULT_TIME)
        self.player = pn.widgets.Player(start=0, end=len(self.engine.times) - 1, value=t0, interval=PLAY_INTERVAL_MS,
                                        loop_policy="once", show_loop_controls=False, width=300, height=60,
                                        visible_buttons=["previous", "pause", "play", "next"],
                                        css_classes=["nd-time"])
        self.player.param.watch(self._schedule_fields, "value")
        # every pane that changes has a fixed size: a pane that grows makes the page lay out again, and Plotly
        # then redraws both figures (hundreds of milliseconds in a browser without a GPU)
        self.time_label = pn.pane.HTML(self._time_text(t0), width=130, height=40)
        self.colour = pn.widgets.RadioButtonGroup(options=["layer", "residence time"], value="layer",
                                                  css_classes=["nd-colour"])
        self.colour.param.watch(self._schedule_fields, "value")
        self.overlay = pn.widgets.Checkbox(name="show a near stored LIGGGHTS run", value=True,
                                           disabled=shared.stored is None)
        self.overlay.param.watch(self._schedule_fields, "value")
        self.numbers = pn.pane.HTML("", stylesheets=[CSS], width=LEFT, height=235)
        self.notes = pn.pane.HTML("", stylesheets=[CSS], width=LEFT, height=95)
        self.particles = pn.pane.Plotly(height=520, width=620, config={"displaylogo": False})
        self.curve = pn.pane.Plotly(height=260, width=620, config={"displaylogo": False})
        self.status = pn.pane.HTML("", width=LEFT, height=24)
        self._show_numbers()
        self._request_fields()
        pn.state.on_session_destroyed(lambda _context: shared.worker.forget(id(self)))

    # ---- layout
    def view(self) -> pn.viewable.Viewable:
        meta = self.engine.model.meta
        inputs = pn.Column(*[pn.Row(self.sliders[k], self.typed[k]) for k in self.engine.inputs])
        controls = pn.Column(
            pn.pane.Markdown(f"### {TITLE}\nmodel `{self.engine.model.name}`: {meta.get('description', '')}; "
                             f"{ranges_line(meta)}", width=LEFT),
            inputs, self.notes, pn.Row(self.player, self.time_label), pn.Row(self.colour, self.overlay),
            self.numbers, pn.pane.HTML(f"<small>{views.held_out_line(meta.get('test_errors', {}))}</small>",
                                       width=LEFT),
            self.status, width=LEFT + 10)
        return pn.Row(controls, pn.Column(self.particles, self.curve))

    # ---- state
    def point(self) -> Point:
        return self.engine.point(self.values)

    def time_index(self) -> int:
        return int(self.player.value)

    def _time_text(self, index: int) -> str:
        return f'<span id="hopper-time">t = {self.engine.times[index]:.2f} s</span> of {self.engine.times[-1]:g} s'

    # ---- input events
    def _slid(self, key: str, event: Any) -> None:
        if self._syncing:
            return
        self.engine.touch()
        self.values[key] = parameter_value(event.new)
        self.clamp_notes.pop(key, None)
        self._show_numbers()  # first: each change goes to the browser as its own message
        self._sync(key, self.values[key])

    def _typed(self, key: str, event: Any) -> None:
        if self._syncing:
            return
        self.engine.touch()
        checked = typed_value(key, event.new, self.engine.solver_limits[key])
        if checked.value is None:
            self.clamp_notes[key] = checked.note
        else:
            self.values[key] = checked.value
            if checked.note:
                self.clamp_notes[key] = checked.note
            else:
                self.clamp_notes.pop(key, None)
        self._show_numbers()
        self._sync(key, self.values[key])
        self._schedule_fields()

    def _sync(self, key: str, value: float) -> None:
        """Slider and text box show the current value (the slider pinned at its end beyond the trained range)."""
        self._syncing = True
        try:
            s, shown = self.sliders[key], min(max(value, self.sliders[key].start), self.sliders[key].end)
            if abs(s.value - shown) > 1e-9:  # not 40.49999999999999 -> 40.5: one more message for nothing
                s.value = shown
            self.typed[key].value = f"{value:g}"
        finally:
            self._syncing = False

    # ---- numbers: in the callback
    def _show_numbers(self) -> None:
        point = self.point()
        gp = self.engine.numbers(point)
        done = self.engine.discharge(point)
        self._field_pending = done is None
        near = self._near_for(self.values)
        self.numbers.object = views.numbers_table(self.values, gp, done.answer if done else None, near,
                                                  "computing ..." if done is None else "")
        notes = list(self.clamp_notes.values()) + gp["warnings"]
        if done is not None:
            notes += range_warnings(done.answer["extrapolation"], "field model",
                                    self.engine.model.meta.get("asked_range"))
        notes.append(self._overlay_note(near))
        self.notes.object = views.notes_html(notes)

    # ---- fields: on the frame thread, drawn on the next tick
    def _schedule_fields(self, *_event: Any) -> None:
        """Ask for the frame once this callback has returned: its numbers go to the browser first."""
        self.doc.add_next_tick_callback(self._request_fields)

    def _request_fields(self) -> None:
        with self._lock:
            self._generation += 1
            generation = self._generation
        request = (self.point(), self.time_index(), self.colour.value, bool(self.overlay.value), dict(self.values))
        self.shared.frames.submit(self._compute_fields, generation, request)

    def _compute_fields(self, generation: int, request: tuple) -> None:
        if generation != self._generation:  # a newer move came in while this one waited
            return
        point, index, colour, overlay, values = request
        try:
            with self.engine.foreground():
                figures = self._figures(point, index, colour, overlay, values)
        except Exception as err:  # shown on the page; the server goes on
            figures = err
        self.doc.add_next_tick_callback(partial(self._draw, generation, point, index, figures))

    def _figures(self, point: Point, index: int, colour: str, overlay: bool, values: dict[str, float]) -> tuple:
        engine = self.engine
        frame = engine.frame(point, index)
        gp = engine.numbers(point)
        near = self._near_for(values)
        stored_particles = stored_curve = None
        if near is not None and overlay:
            t_stored, q = self.shared.stored.particles(near.sim_id, frame.time, STORED_SHOWN)
            stored_particles = (f"{near.sim_id} (LIGGGHTS, t = {t_stored:.2f} s)", q)
            stored_curve = (f"{near.sim_id} (LIGGGHTS)", engine.times,
                            self.shared.stored.remaining(near.sim_id, engine.times))
        title = f"{views.point_text(values)}, t = {frame.time:.2f} s"
        residence_max = max(1.0, math.ceil(2 * float(np.nan_to_num(gp["high"]["drainage_time"], nan=1.0))) / 2)
        particles = views.particles_figure(frame, "layer" if colour == "layer" else "residence",
                                           engine.settings.n_layers, np.asarray(engine.norm.box_lo),
                                           np.asarray(engine.norm.box_hi), title, residence_max, stored_particles)
        done = engine.discharge(point)
        t_end = float(np.nan_to_num(gp["high"]["drainage_time"], nan=engine.times[-1]))
        t_max = float(min(engine.times[-1], max(2 * math.ceil(t_end), frame.time + 0.5)))
        curve = views.discharge_figure(gp_discharge_sketch(gp["mean"], float(engine.times[-1])),
                                       (gp["low"]["drainage_t95"], gp["high"]["drainage_t95"]),
                                       (done.times, done.remaining) if done else None, stored_curve,
                                       frame.time, t_max)
        return particles, curve, frame

    def _overlay_note(self, near: Any) -> str:
        stored = self.shared.stored
        if near is not None:
            return f"stored run shown: {near.label()}"
        if stored is None:
            return self.shared.stored_note
        return (f"no stored LIGGGHTS run near this point (none within {100 * stored.near:g} % of each trained "
                f"range; {len(stored.records)} stored at {stored.dataset_dir})")

    def _near_for(self, values: dict[str, float]) -> Any:
        return self.shared.stored.nearest(values) if self.shared.stored is not None else None

    def _draw(self, generation: int, point: Point, index: int, figures: Any) -> None:
        if generation != self._generation:
            return
        if isinstance(figures, Exception):
            self.status.object = f'<span id="hopper-error" style="color:#b00">{html.escape(str(figures))}</span>'
            return
        particles, curve, frame = figures
        self.particles.object = particles
        self.curve.object = curve
        self.time_label.object = self._time_text(index)
        step = float(self.engine.times[1] - self.engine.times[0])
        self.status.object = (f'<small id="hopper-status" data-model="{self.engine.model.name}" '
                              f'data-point="{views.point_text(self.engine.values(point))}" data-time="{frame.time:g}" '
                              f'data-step="{step:g}" data-frame-ms="{1000 * frame.seconds:.1f}">'
                              f'frame: {1000 * frame.seconds:.0f} ms</small>')
        if self.engine.discharge(point) is None:
            self.shared.worker.want(id(self), point, partial(self._discharge_done, point))
        elif self._field_pending and point == self.point():  # done meanwhile (for another session)
            self._show_numbers()

    # ---- the whole discharge: from the background worker
    def _discharge_done(self, point: Point) -> None:
        self.doc.add_next_tick_callback(partial(self._discharge_drawn, point))

    def _discharge_drawn(self, point: Point) -> None:
        if point == self.point():
            self._show_numbers()
            self._request_fields()


def page(shared: HopperShared) -> pn.viewable.Viewable:
    return HopperPage(shared).view()
