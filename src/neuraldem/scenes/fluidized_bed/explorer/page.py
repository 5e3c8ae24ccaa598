"""The fluidized-bed page: an inlet-velocity slider (and a box for a typed value), a time player, the solid
fraction and mixing on the central slice (animated), the bed height, bubble fraction and Lacey curves, and
the numbers with the models' held-out errors beside CFD-DEM's own spread.

A move updates in two steps so the cheap answer never waits for the costly one:
1. numbers (GP, about a millisecond) in the widget's own callback, sent to the browser at once;
2. the fields and curves on the session's next tick, from the rollout nearest the velocity that is ready (the
   lattice computed at server start, or the exact one), labelled with its velocity: a rollout takes seconds,
   so what a move shows at once is the nearest ready one, never a new computation.
The exact rollout (the field model's numbers, as `neuraldem predict fb`) runs on the background worker once
the slider rests, and replaces the nearest one when done.
"""

from __future__ import annotations

import html
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import panel as pn

from neuraldem import pretrained
from neuraldem.scenes.fluidized_bed.explorer import views
from neuraldem.scenes.fluidized_bed.explorer.engine import KEY, STEP, BedEngine, BedRollout
from neuraldem.scenes.fluidized_bed.explorer.worker import RolloutWorker
from neuraldem.scenes.parameters import range_warnings, ranges_line
from neuraldem.serve.inputs import parameter_value, typed_value
from neuraldem.serve.markup import CSS

SCENE_KIND = "fluidized_bed"
TITLE = "Fluidized bed"
DEFAULT_VELOCITY = 1.8  # [m/s] `neuraldem predict fb`'s example
PLAY_INTERVAL_MS = 150
READY_CHECK_MS = 1000  # a session looks this often for a newly ready lattice rollout nearer its velocity
LEFT = 480  # width of the controls column [px]


@dataclass
class BedShared:
    """What every session of the bed page shares: the loaded model, its caches and the background worker."""

    engine: BedEngine
    worker: RolloutWorker


def prepare(model_name: str | None, dataset: Path | None, near: float) -> BedShared:
    """Load the bed model (files verified: a missing or damaged one is a DataError) and start the lattice of
    background rollouts. `dataset` and `near` (stored runs beside the model) are the hopper page's: the bed
    page has no stored-run overlay."""
    model = pretrained.load(model_name or pretrained.default_for(SCENE_KIND), SCENE_KIND)
    engine = BedEngine(model)
    return BedShared(engine, RolloutWorker(engine))


def default_velocity(engine: BedEngine) -> float:
    lo, hi = engine.slider_range()
    return parameter_value(min(max(DEFAULT_VELOCITY, lo), hi))


class BedPage:
    """One browser session's page."""

    def __init__(self, shared: BedShared):
        self.shared, self.engine = shared, shared.engine
        self.doc = pn.state.curdoc
        self.velocity = default_velocity(self.engine)
        self.clamp_note = ""
        self._syncing = False
        self._generation = 0
        self._drawn: tuple[float | None, int] = (None, -1)  # (rollout velocity shown, lattice ready) when drawn
        lo, hi = self.engine.slider_range()
        self.slider = pn.widgets.FloatSlider(name="inlet velocity [m/s]", start=lo, end=hi, step=STEP,
                                             value=self.velocity, width=260, css_classes=[f"nd-slider-{KEY}"])
        self.typed = pn.widgets.TextInput(value=f"{self.velocity:g}", width=90, css_classes=[f"nd-typed-{KEY}"])
        self.slider.param.watch(self._slid, "value")
        self.typed.param.watch(self._typed, "value")
        # the player starts at the Lacey time (the third answer's moment)
        lacey = self.engine.window.lacey_time
        t0 = min(range(self.engine.n_frames), key=lambda i: abs(self.engine.frame_time(i) - lacey))
        self.player = pn.widgets.Player(start=0, end=self.engine.n_frames - 1, value=t0, interval=PLAY_INTERVAL_MS,
                                        loop_policy="loop", show_loop_controls=False, width=300, height=60,
                                        visible_buttons=["previous", "pause", "play", "next"],
                                        css_classes=["nd-time"])
        self.player.param.watch(self._schedule_fields, "value")
        # fixed sizes: a pane that grows lays the page out again, and Plotly then redraws both figures
        self.time_label = pn.pane.HTML("", width=130, height=40)
        self.numbers = pn.pane.HTML("", stylesheets=[CSS], width=LEFT, height=120)
        self.notes = pn.pane.HTML("", stylesheets=[CSS], width=LEFT, height=95)
        self.fields = pn.pane.Plotly(height=470, width=560, config={"displaylogo": False})
        self.curves = pn.pane.Plotly(height=380, width=560, config={"displaylogo": False})
        self.status = pn.pane.HTML("", width=LEFT, height=40)
        self._show_numbers()
        self._draw(self._generation)
        self.shared.worker.want(id(self), self.velocity, self._rollout_done(self.velocity))
        pn.state.on_session_destroyed(lambda _context: shared.worker.forget(id(self)))
        pn.state.add_periodic_callback(self._check_ready, period=READY_CHECK_MS)

    # ---- layout
    def view(self) -> pn.viewable.Viewable:
        meta = self.engine.model.meta
        w = self.engine.window
        controls = pn.Column(
            pn.pane.Markdown(f"### {TITLE}\nmodel `{self.engine.model.name}`: {meta.get('description', '')}. "
                             f"Answers over {w.duration:g} s from snapshot 1; Lacey index at {w.lacey_time:g} s; "
                             f"{ranges_line(meta)}.",
                             width=LEFT),
            pn.Row(self.slider, self.typed), self.notes, pn.Row(self.player, self.time_label), self.numbers,
            pn.pane.HTML(views.held_out_table(meta.get("test_errors", {})), stylesheets=[CSS], width=LEFT),
            pn.pane.HTML("<small>The fields shown at once are the nearest rollout already computed (a lattice over "
                         "the trained range, computed at server start, and every velocity computed since), "
                         "labelled with its velocity; the exact rollout (seconds) follows once the slider rests."
                         "</small>", width=LEFT),
            self.status, width=LEFT + 10)
        return pn.Row(controls, pn.Column(self.fields, self.curves))

    # ---- input events
    def _slid(self, event: Any) -> None:
        if self._syncing:
            return
        self.engine.touch()
        self.velocity = parameter_value(event.new)
        self.clamp_note = ""
        self._moved()

    def _typed(self, event: Any) -> None:
        if self._syncing:
            return
        self.engine.touch()
        checked = typed_value(KEY, event.new, self.engine.solver_limits)
        self.clamp_note = checked.note
        if checked.value is not None:
            self.velocity = checked.value
        self._moved()

    def _moved(self) -> None:
        self._show_numbers()  # first: each change goes to the browser as its own message
        self._sync()
        self.shared.worker.want(id(self), self.velocity, self._rollout_done(self.velocity))
        self._schedule_fields()

    def _sync(self) -> None:
        """Slider and text box show the current value (the slider pinned at its end beyond the trained range)."""
        self._syncing = True
        try:
            shown = min(max(self.velocity, self.slider.start), self.slider.end)
            if abs(self.slider.value - shown) > 1e-9:
                self.slider.value = shown
            self.typed.value = f"{self.velocity:g}"
        finally:
            self._syncing = False

    # ---- numbers: in the callback
    def _show_numbers(self) -> None:
        v = self.velocity
        gp = self.engine.numbers(v)
        exact = self.engine.rollout(v)
        failed = self.shared.worker.failed.get(v)
        state = f"failed: {failed}" if failed else "computing ... (once the slider rests)"
        self.numbers.object = views.numbers_table(v, gp, exact, state, self.engine.quantities)
        notes = ([self.clamp_note] if self.clamp_note else []) + gp["warnings"]
        if exact is not None:
            notes += range_warnings(exact.extrapolation, "field model", self.engine.model.meta.get("asked_range"))
            if exact.diverged_at is not None:
                notes.append(f"warning: the rollout diverged at step {exact.diverged_at}: no field-model answers")
            notes.append(f"rollout started from {exact.start}")
        self.notes.object = views.notes_html(notes)

    # ---- fields: on the next tick, so the numbers reach the browser first
    def _schedule_fields(self, *_event: Any) -> None:
        self._generation += 1
        self.doc.add_next_tick_callback(lambda g=self._generation: self._draw(g))

    def _draw(self, generation: int) -> None:
        if generation != self._generation:  # a newer move came in meanwhile: draw that one
            return
        engine, v, index = self.engine, self.velocity, int(self.player.value)
        try:
            r = engine.nearest_ready(v)
            state = engine.frame_state(r, index) if r is not None else 0
            t = float(r.times[state]) if r is not None else engine.frame_time(index)
            self.fields.object = views.fields_figure(v, r, state, engine.x_centres, engine.z_centres)
            self.curves.object = views.curves_figure(v, engine.numbers(v), r, t, engine.quantities,
                                                     engine.window.lacey_time)
        except Exception as err:  # shown on the page; the server goes on
            self.status.object = f'<span id="bed-error" style="color:#b00">{html.escape(str(err))}</span>'
            return
        self._drawn = (None if r is None else r.velocity, engine.lattice_ready())
        self.time_label.object = f'<span id="bed-time">t = {t:.2f} s</span>'
        self.status.object = self._status_html(v, r, t)

    def _status_html(self, v: float, r: BedRollout | None, t: float) -> str:
        engine = self.engine
        ready = engine.lattice_ready()
        what = "no rollout ready yet" if r is None else \
            f"shown: rollout at {r.velocity:g} m/s ({'exact' if r.velocity == v else 'nearest ready'})"
        return (f'<small id="bed-status" data-model="{engine.model.name}" data-velocity="{v!r}" '
                f'data-shown="{"" if r is None else repr(r.velocity)}" data-time="{t:g}" '
                f'data-frame="{int(self.player.value)}" '
                f'data-frames="{engine.n_frames}" data-lattice="{len(engine.lattice)}" data-ready="{ready}">'
                f"{what}; lattice rollouts ready: {ready} of {len(engine.lattice)} "
                f"({', '.join(f'{x:g}' for x in engine.lattice)} m/s)</small>")

    def _check_ready(self) -> None:
        """Redraw when a lattice rollout finished since the last draw (a nearer one may now be ready)."""
        r = self.engine.nearest_ready(self.velocity)
        if self._drawn != (None if r is None else r.velocity, self.engine.lattice_ready()):
            self._schedule_fields()

    # ---- the exact rollout: from the background worker
    def _rollout_done(self, v: float) -> Any:
        def done() -> None:
            self.doc.add_next_tick_callback(lambda: self._rollout_drawn(v))
        return done

    def _rollout_drawn(self, v: float) -> None:
        if v == self.velocity:
            self._show_numbers()
            self._schedule_fields()


def page(shared: BedShared) -> pn.viewable.Viewable:
    return BedPage(shared).view()
