"""The hopper explorer's answers, cached per parameter point, with no web code: what the page shows and the
tests and the benchmark call directly.

A slider move must answer fast, so the work is split by what it costs:
- numbers: the scalar GP (milliseconds), the same call and formatting as `neuraldem predict hopper fields=false`;
- the shown frame: the field model at one time on the drawn material (a subset of the lattice the model fills
  at t = 0, cached per point), tens of milliseconds; frames are cached per point and time (play);
- the whole discharge: the field model at every 0.1 s on all the material, as `neuraldem predict` computes it
  (seconds), done in the background, in chunks so a newer point cancels it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from neuraldem import pretrained
from neuraldem.scenes.hopper.predict import hopper_gp, hopper_net
from neuraldem.scenes.parameters import range_warnings
from neuraldem.serve.cache import LruCache
from neuraldem.serve.inputs import parameter_value

TIME_STRIDE = 2  # frames every 2nd time of the 0.05 s grid (0.1 s), the grid `neuraldem predict` answers on
# times per forward call of the whole discharge, as whatif.field_answer: the same calls give the same numbers
# to the last bit (other chunkings differ by float rounding, which a model that barely drains turns into
# visible t95 differences); a frame asked for meanwhile does not wait: this work runs niced
TIMES_PER_CALL = 16
# lattice points drawn at most (a fixed random subset): a browser without a GPU draws a few thousand 3D markers
# in a few hundred milliseconds, and a frame of a new point is computed on these alone
MAX_SHOWN = 2000
QUIET_S = 0.5  # the whole discharge is computed once no move came for this long
OCCUPIED = 0.5  # occupancy threshold of the material at t = 0 and of the drawn particles

Point = tuple[float, ...]  # parameter values in the model's input order


@dataclass(frozen=True)
class Material:
    """Where the model puts material at t = 0 for one point: the query points of every later frame."""

    points: np.ndarray  # (Q, 3) occupied lattice points (as whatif.field_answer)
    layer_edges: np.ndarray  # initial-height layer edges (metrics.layer_edges of the points)


@dataclass(frozen=True)
class Frame:
    """The drawn particles at one time: occupied points with their initial layer and residence time."""

    time: float
    positions: np.ndarray  # (M, 3)
    layer: np.ndarray  # (M,) 0 = bottom layer
    residence: np.ndarray  # (M,) seconds until the material leaves
    seconds: float  # compute time


@dataclass(frozen=True)
class Discharge:
    """The field model over the whole discharge: its numbers (as `predict`) and its curve."""

    answer: dict[str, Any]  # summary, regime, seconds, n_points, extrapolation (predict's "field" entry)
    times: np.ndarray
    remaining: np.ndarray  # share of the initial material still in the hopper
    fields: Any  # TrajectoryFields at every time of `times`, on Material.points


class HopperEngine:
    """One shipped hopper model, loaded once per server and shared by every browser session."""

    def __init__(self, model: pretrained.Pretrained, cache_points: int = 64, cache_frames: int = 512):
        from neuraldem.data.normalization import HopperNormalizer
        from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings
        from neuraldem.scenes.hopper.parameters import PARAMETERS
        from neuraldem.scenes.hopper.solver import HopperScene
        from neuraldem.scenes.hopper.surrogate.predictors import time_grid

        self.model = model
        self.inputs: list[str] = list(model.meta["inputs"])
        self.trained_range = {k: tuple(v) for k, v in model.meta["trained_range"].items()}
        self.solver_limits = {k: PARAMETERS.limits(k) for k in self.inputs}
        self.settings = HopperMetricSettings.from_config(model.meta.get("metric_settings", {}),
                                                         f"{model.name} metric_settings")
        self.gp = hopper_gp(model)
        self.net, self.meta = hopper_net(model)  # ONNX Runtime when the model has its export: frames in ms
        self.norm = HopperNormalizer.from_dict(self.meta["normalizer"])
        hop = self.meta["scene"]["hopper"]
        self.scene = HopperScene.from_config(hop, "model scene")
        self.times = time_grid(self.norm.horizon, float(hop["snapshot_interval"]))[::TIME_STRIDE]
        self._numbers: LruCache[dict[str, Any]] = LruCache(cache_points * 4)
        self._material: LruCache[Material] = LruCache(cache_points)
        self._drawn: LruCache[Material] = LruCache(cache_points)
        self._frames: LruCache[Frame] = LruCache(cache_frames)
        self._discharge: LruCache[Discharge] = LruCache(cache_points)
        self._frames_running = 0
        self._last_activity = time.monotonic()
        self._activity = threading.Condition()

    # ---- the page first: the background work waits while a person moves things
    def touch(self) -> None:
        """A person moved something: the whole-discharge work pauses until QUIET_S passed without a move."""
        with self._activity:
            self._last_activity = time.monotonic()

    @contextmanager
    def foreground(self) -> Iterator[None]:
        """Mark a frame being answered (the whole-discharge work pauses between its chunks meanwhile)."""
        with self._activity:
            self._frames_running += 1
            self._last_activity = time.monotonic()
        try:
            yield
        finally:
            with self._activity:
                self._frames_running -= 1
                self._last_activity = time.monotonic()
                self._activity.notify_all()

    def _wait_until_quiet(self, longest: float = 10.0) -> None:
        """Block the background work while frames are answered and until QUIET_S after the last move (at most
        `longest`, so it cannot starve): on two busy cores a concurrent chunk doubles a move's latency."""
        end = time.monotonic() + longest
        with self._activity:
            while (now := time.monotonic()) < end:
                quiet_for = now - self._last_activity
                if self._frames_running == 0 and quiet_for >= QUIET_S:
                    return
                self._activity.wait(timeout=max(QUIET_S - quiet_for, 0.02))

    # ---- points
    def point(self, values: dict[str, float]) -> Point:
        return tuple(parameter_value(values[k]) for k in self.inputs)

    def values(self, point: Point) -> dict[str, float]:
        return dict(zip(self.inputs, point, strict=True))

    def time_index(self, t: float) -> int:
        return int(np.argmin(np.abs(self.times - t)))

    # ---- numbers
    def numbers(self, point: Point) -> dict[str, Any]:
        """The GP's answer as `neuraldem predict hopper json=true` prints it under "gp", and its range warnings."""
        return self._numbers.get_or_compute(point, lambda: self._gp_numbers(point))

    def _gp_numbers(self, point: Point) -> dict[str, Any]:
        from neuraldem.models.scalar_baselines import gp_answers
        from neuraldem.scenes.hopper.whatif import regime

        a = gp_answers(self.gp, [self.values(point)])[0]
        index = (a.mean["mass_flow_index"], a.low["mass_flow_index"], a.high["mass_flow_index"])
        return {"mean": a.mean, "low": a.low, "high": a.high, "seconds": a.seconds,
                "regime": f"{regime(index[0], self.settings)} ({index[0]:.2f} [{index[1]:.2f}, {index[2]:.2f}])",
                "extrapolation": a.extrapolation, "warnings": range_warnings(a.extrapolation, "GP",
                                                                            self.model.meta.get("asked_range"))}

    # ---- fields
    def _predictor(self) -> Any:
        """A fresh predictor per call: it records per-run state, and the page and the worker run at once."""
        from neuraldem.scenes.hopper.whatif import predictor_for

        predictor = predictor_for(self.net, self.meta)
        predictor.times_per_call = TIMES_PER_CALL
        return predictor

    def _record(self, point: Point) -> Any:
        from neuraldem.data.manifest import SimRecord

        return SimRecord("what-if", 0, self.values(point))

    def _lattice(self, point: Point) -> np.ndarray:
        from neuraldem.scenes.hopper.whatif import lattice_points

        alpha = self.values(point).get("alpha", 0.0)
        return lattice_points(self.scene, alpha, np.asarray(self.norm.box_lo), np.asarray(self.norm.box_hi))

    def _occupied_at_start(self, point: Point, lattice: np.ndarray) -> np.ndarray:
        from neuraldem.errors import DataError

        start = self._predictor().fields(self._record(point), np.array([0.0]), lattice).occupancy[0]
        points = lattice[start >= OCCUPIED]
        if len(points) == 0:
            raise DataError(f"the field model sees no material at t = 0 for {self.values(point)}",
                            "ask within the trained ranges, or read the GP answer")
        return points

    def material(self, point: Point) -> Material:
        """All the material at t = 0, as `whatif.field_answer` finds it: the points of the whole discharge."""
        from neuraldem.scenes.hopper.analysis.metrics import layer_edges

        def fill() -> Material:
            points = self._occupied_at_start(point, self._lattice(point))
            return Material(points, layer_edges(points[:, 2], self.settings.n_layers))

        return self._material.get_or_compute(point, fill)

    def drawn(self, point: Point) -> Material:
        """The material drawn: the same, found on a fixed random subset of MAX_SHOWN lattice points (a frame
        of a new point then costs a fraction of the whole material's)."""
        from neuraldem.scenes.hopper.analysis.metrics import layer_edges

        def fill() -> Material:
            lattice = self._lattice(point)
            if len(lattice) > MAX_SHOWN:
                lattice = lattice[np.sort(np.random.default_rng(0).choice(len(lattice), MAX_SHOWN, replace=False))]
            points = self._occupied_at_start(point, lattice)
            return Material(points, layer_edges(points[:, 2], self.settings.n_layers))

        return self._drawn.get_or_compute(point, fill)

    def frame(self, point: Point, index: int) -> Frame:
        """The drawn particles at time `self.times[index]`: the field model at that one time."""
        return self._frames.get_or_compute((point, index), lambda: self._one_frame(point, index))

    def _one_frame(self, point: Point, index: int) -> Frame:
        from neuraldem.scenes.hopper.analysis.metrics import layer_of

        t0 = time.perf_counter()
        m = self.drawn(point)
        f = self._predictor().fields(self._record(point), self.times[index:index + 1], m.points)
        occupied = f.occupancy[0] >= OCCUPIED
        layer = layer_of(f.transport[0][occupied, 2], m.layer_edges)
        residence = np.maximum(f.residence[0][occupied], 0.0)
        return Frame(float(self.times[index]), m.points[occupied], layer, residence, time.perf_counter() - t0)

    # ---- the whole discharge
    def discharge(self, point: Point) -> Discharge | None:
        """The whole discharge when it has been computed, else None (see `compute_discharge`)."""
        return self._discharge.get(point)

    def compute_discharge(self, point: Point, cancelled: Callable[[], bool] = lambda: False) -> Discharge | None:
        """The numbers as `neuraldem predict` answers them (`whatif.field_answer` with its query budget: the same
        calls, the same numbers), then the field model at every frame time for the curve and the particles, chunk
        by chunk (None when `cancelled()` turns true between chunks, paused while a frame is answered)."""
        from neuraldem.scenes.hopper.analysis.metrics import occupied_counts
        from neuraldem.scenes.hopper.surrogate.predictors import TrajectoryFields
        from neuraldem.scenes.hopper.whatif import ANSWER_BUDGET, field_answer, regime

        found = self._discharge.get(point)
        if found is not None:
            return found
        t0 = time.perf_counter()
        numbers = field_answer(self.net, self.meta, self.values(point), self.settings,
                               budget=ANSWER_BUDGET)
        m, predictor, rec = self.material(point), self._predictor(), self._record(point)
        parts = []
        for k in range(0, len(self.times), TIMES_PER_CALL):
            self._wait_until_quiet()
            if cancelled():
                return None
            parts.append(predictor.fields(rec, self.times[k:k + TIMES_PER_CALL], m.points))
        fields = TrajectoryFields(self.times, *(np.concatenate([getattr(p, name) for p in parts])
                                               for name in ("occupancy", "transport", "residence")))
        index = numbers.summary["mass_flow_index"]
        answer = {"summary": numbers.summary, "regime": f"{regime(index, self.settings)} ({index:.2f})",
                  "seconds": time.perf_counter() - t0, "numbers_s": numbers.seconds, "n_points": len(numbers.points),
                  "extrapolation": numbers.extrapolation}
        remaining = occupied_counts(fields.occupancy) / len(m.points)
        return self._discharge.put(point, Discharge(answer, self.times, remaining, fields))


def gp_discharge_sketch(mean: dict[str, float], horizon: float, margin: float = 0.01,
                        window: tuple[float, float] = (0.2, 0.95)) -> tuple[np.ndarray, np.ndarray]:
    """The discharge curve drawn through the GP's numbers, shown at once while the field model's curve is
    computed: a start-up to the first 20 % of the discharged material, a straight line at the GP's outflow
    rate to t95, the 1 %-rule drainage time, then the residual. A sketch, labelled as one on the page."""
    residual = float(np.clip(mean.get("residual_fraction", 0.0), 0.0, 1.0))
    rate, t95 = mean.get("outflow_rate", np.nan), mean.get("drainage_t95", np.nan)
    d = 1.0 - residual
    if not (np.isfinite(rate) and np.isfinite(t95) and rate > 0 and d > 0):
        return np.array([0.0, horizon]), np.array([1.0, 1.0])
    t_a = max(t95 - (window[1] - window[0]) * d / rate, 0.0)
    knots = [(0.0, 1.0), (t_a, 1.0 - window[0] * d), (t95, 1.0 - window[1] * d)]
    t_end = mean.get("drainage_time", np.nan)
    if np.isfinite(t_end) and t_end > t95:
        knots.append((t_end, residual + margin))
    knots.append((max(horizon, knots[-1][0]), residual))
    t, level = zip(*[k for i, k in enumerate(knots) if i == 0 or k[0] > knots[i - 1][0]], strict=True)
    return np.array(t), np.array(level)
