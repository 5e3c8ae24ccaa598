"""The fluidized-bed explorer's answers, cached per inlet velocity, with no web code: what the bed page shows
and the tests and the benchmark call directly.

Split by what it costs:
- numbers: the scalar GP (about a millisecond), the same call as `neuraldem predict fluidized_bed
  fields=false`;
- fields: a rollout of the field model over the answer window (a few hundred steps, seconds to tens of
  seconds on two busy cores), as `neuraldem predict fluidized_bed` runs it: too slow for a slider move.
  Rollouts are therefore computed in the background (`fb_worker.py`) at a lattice of velocities over the
  trained range and at the exact velocity once the slider rests; a move shows the nearest ready rollout at
  once, labelled with its velocity, and the exact one when it is done. Only the central y slice of the grid
  (the bed is quasi-2D) and the curves are kept per rollout.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from neuraldem import pretrained
from neuraldem.scenes.parameters import range_warnings
from neuraldem.serve.cache import LruCache
from neuraldem.serve.inputs import parameter_value

KEY = "inlet_velocity"
STEP = 0.01  # [m/s] slider step; lattice velocities lie on it
# background rollouts over the trained range, at server start, one after the other: stepped as one batch they
# would be at most ~1.4 - 1.6x faster per member, and no longer the rollouts `predict` makes
# (results/fluidized_bed/speed/fb_batch.md)
LATTICE = 9
QUIET_S = 0.5  # the background rollouts step only after this long without a move
FRAMES = 60  # the time player's frames over the window at most (every `stride`-th rollout state)
MIX_BLANK = 0.02  # mixing is not drawn where the solid fraction is at most this (plots.animate_fields)
SEED = 0  # `neuraldem predict fb`'s default seed: the same rollout, the same numbers
RUNTIME = "auto"  # and its default runtime


class Superseded(Exception):
    """A background rollout nobody wants any more (stopped between two steps)."""


@dataclass(frozen=True)
class BedRollout:
    """One rollout as the page draws it: the central y slice of the fields, the curves and the answers."""

    velocity: float
    times: np.ndarray  # (T,) [s]
    solid_fraction: np.ndarray  # (T, nx, nz) float32, central y slice
    mixing: np.ndarray  # (T, nx, nz) float32, NaN where the solid fraction <= MIX_BLANK
    curves: Any  # whatif.BedCurves
    summary: dict[str, float]  # predict's "field" "summary"
    seconds: float
    start: str  # the shipped first state it started from
    extrapolation: dict[str, list[float]]
    diverged_at: int | None


def spread_order(values: list[float], first: float) -> list[float]:
    """`values` starting with the one nearest `first`, then each time the one farthest from those taken (the
    lattice fills evenly: an early move finds a rollout not far off)."""
    rest = sorted(set(values))
    if not rest:
        return []
    order = [min(rest, key=lambda v: abs(v - first))]
    rest.remove(order[0])
    while rest:
        nxt = max(rest, key=lambda v: min(abs(v - o) for o in order))
        order.append(nxt)
        rest.remove(nxt)
    return order


class BedEngine:
    """One shipped bed model, loaded once per server and shared by every browser session."""

    def __init__(self, model: pretrained.Pretrained, lattice: int = LATTICE, cache_rollouts: int = 32):
        from neuraldem.models.modules import compiled

        compiled.warm_up_in_background()  # the rollout's compiled numerics, while the model loads
        from neuraldem.scenes.fluidized_bed.parameters import PARAMETERS
        from neuraldem.scenes.fluidized_bed.predict import fb_field_model
        from neuraldem.scenes.fluidized_bed.whatif import load_gp, quantities

        self.model = model
        lo, hi = (float(x) for x in model.meta["trained_range"][KEY])
        self.trained_range = (lo, hi)
        self.solver_limits = tuple(float(x) for x in PARAMETERS.limits(KEY))
        self.module, self.states, self.settings, self.window = fb_field_model(model, "predict")
        self.quantities = quantities(self.window.lacey_time)
        self.gp = load_gp(model.file("gp"))
        g = self.states.grid
        self.x_centres = 1000 * (g.lo[0] + (np.arange(g.shape[0]) + 0.5) * (g.hi[0] - g.lo[0]) / g.shape[0])
        self.z_centres = 1000 * (g.lo[2] + (np.arange(g.shape[2]) + 0.5) * (g.hi[2] - g.lo[2]) / g.shape[2])
        n_states = self.window.steps + 1
        self.stride = max(1, math.ceil((n_states - 1) / FRAMES))
        steps = np.arange(0, n_states, self.stride)  # the rollout state of each player frame, the last included
        self.frame_steps = steps if steps[-1] == n_states - 1 else np.append(steps, n_states - 1)
        self.lattice = self.lattice_velocities(lattice)
        self._numbers: LruCache[dict[str, Any]] = LruCache(1024)
        self._exact: LruCache[BedRollout] = LruCache(cache_rollouts)
        self._lattice_done: dict[float, BedRollout] = {}
        self._lock = threading.Lock()
        self._last_move = time.monotonic() - QUIET_S
        self._moving = threading.Condition()

    # ---- velocities
    def velocity(self, v: float) -> float:
        return parameter_value(v)

    def slider_range(self) -> tuple[float, float]:
        lo, hi = self.trained_range
        return (parameter_value(math.ceil(lo / STEP - 1e-9) * STEP),
                parameter_value(math.floor(hi / STEP + 1e-9) * STEP))

    def lattice_velocities(self, n: int) -> list[float]:
        """`n` velocities evenly over the slider's range, on its step grid."""
        lo, hi = self.slider_range()
        if n <= 1 or hi <= lo:
            return [parameter_value(round((lo + hi) / 2 / STEP) * STEP)]
        return sorted({parameter_value(round((lo + i * (hi - lo) / (n - 1)) / STEP) * STEP) for i in range(n)})

    # ---- a person first
    def touch(self) -> None:
        """A person moved something: background rollouts pause until QUIET_S passed without a move."""
        with self._moving:
            self._last_move = time.monotonic()

    def wait_until_quiet(self, longest: float = 10.0) -> None:
        """Block a background rollout between steps while a person moves (at most `longest`: no starvation).
        On two busy cores a concurrent step, holding Python's lock while the OS has it waiting, would double a
        move's latency."""
        end = time.monotonic() + longest
        with self._moving:
            while (now := time.monotonic()) < end and (quiet := now - self._last_move) < QUIET_S:
                self._moving.wait(timeout=max(QUIET_S - quiet, 0.02))

    # ---- numbers
    def numbers(self, v: float) -> dict[str, Any]:
        """The GP's answer as `neuraldem predict fluidized_bed json=true` prints it under "gp", and its range
        warnings."""
        v = self.velocity(v)
        return self._numbers.get_or_compute(v, lambda: self._gp_numbers(v))

    def _gp_numbers(self, v: float) -> dict[str, Any]:
        from neuraldem.models.scalar_baselines import gp_answers

        a = gp_answers(self.gp, [{KEY: v}])[0]
        return {"mean": a.mean, "low": a.low, "high": a.high, "seconds": a.seconds,
                "extrapolation": a.extrapolation, "warnings": range_warnings(a.extrapolation, "GP",
                                                                            self.model.meta.get("asked_range"))}

    # ---- rollouts
    def rollout(self, v: float) -> BedRollout | None:
        """The rollout at exactly `v` when it is done (None otherwise)."""
        v = self.velocity(v)
        with self._lock:
            found = self._lattice_done.get(v)
        return found if found is not None else self._exact.get(v)

    def nearest_ready(self, v: float) -> BedRollout | None:
        """The exact rollout when done, else the ready lattice rollout nearest in velocity (None: none yet)."""
        exact = self.rollout(v)
        if exact is not None:
            return exact
        with self._lock:
            ready = list(self._lattice_done.values())
        return min(ready, key=lambda r: (abs(r.velocity - v), r.velocity)) if ready else None

    def lattice_ready(self) -> int:
        with self._lock:
            return len(self._lattice_done)

    def compute(self, v: float, gate: Callable[[], None] | None = None) -> BedRollout:
        """The rollout at `v` by `whatif.field_answer`, as `neuraldem predict fb` runs it (the shipped first state
        nearest in velocity, the same stepper, seed, runtime, threads and steps); `gate` runs before every step."""
        from neuraldem.scenes.fluidized_bed.whatif import field_answer

        v = self.velocity(v)
        done = self.rollout(v)
        if done is not None:
            return done
        f = field_answer(self.module, self.states, v, self.settings, self.window, SEED, runtime=RUNTIME, gate=gate)
        r = f.rollout
        mid = r.solid_fraction.shape[2] // 2
        sf = np.ascontiguousarray(r.solid_fraction[:, :, mid, :], dtype=np.float32)
        mix = np.where(sf > MIX_BLANK, r.mixing[:, :, mid, :], np.nan).astype(np.float32)
        out = BedRollout(v, np.asarray(r.times, dtype=np.float64), sf, mix, f.curves, f.summary, f.seconds, f.start,
                         f.extrapolation, r.diverged_at)
        with self._lock:
            if v in self.lattice:
                self._lattice_done[v] = out
                return out
        return self._exact.put(v, out)

    # ---- the time player
    @property
    def n_frames(self) -> int:
        return len(self.frame_steps)

    def frame_time(self, index: int) -> float:
        return float(self.window.dt * (self.frame_steps[index] + _start_snapshot()))

    def frame_state(self, r: BedRollout, index: int) -> int:
        """The rollout state of player frame `index` (its last one when the rollout stopped early)."""
        return int(min(self.frame_steps[index], len(r.times) - 1))


def _start_snapshot() -> int:
    from neuraldem.scenes.fluidized_bed.whatif import START_SNAPSHOT

    return START_SNAPSHOT
