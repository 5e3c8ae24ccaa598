"""The bed page's background rollouts: one thread per server, at a lower CPU priority.

Work in this order: the exact velocity a session rests on (the newest wanted first), then the lattice over the
trained range (filled at server start, so a slider move always finds a rollout near it). A rollout steps only
after QUIET_S without a move; an exact one nobody wants any more, or a lattice one while an exact one waits,
stops between two steps (a stopped lattice rollout is redone later). Sessions whose velocity is done are called
back from this thread.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable, Hashable
from typing import Any

from neuraldem.scenes.fluidized_bed.explorer.engine import Superseded
from neuraldem.serve.workers import SessionWants, lower_priority

Callback = Callable[[], None]


class RolloutWorker(SessionWants):
    def __init__(self, engine: Any, start: bool = True):
        super().__init__()
        self.engine = engine
        self.computed: list[float] = []  # velocities rolled out, in order (tests and the page read it)
        self.failed: dict[float, str] = {}
        mid = sum(engine.trained_range) / 2
        from neuraldem.scenes.fluidized_bed.explorer.engine import spread_order

        self._lattice = spread_order(engine.lattice, mid)
        self._thread = threading.Thread(target=self._run, name="bed-rollouts", daemon=True)
        if start:
            self._thread.start()
            self._wake.set()

    def want(self, session: Hashable, velocity: float, done: Callback) -> None:
        """Session `session` now wants the rollout at `velocity` (replacing what it wanted before)."""
        with self._lock:
            self._wanted.pop(session, None)  # re-inserted last: the newest wanted
            self._wanted[session] = (velocity, done)
        self._wake.set()

    def _exact_todo(self) -> float | None:
        """The newest wanted velocity not done; sessions whose velocity is done are called back."""
        return self._pending(lambda v: self.engine.rollout(v) is not None, skip=self.failed)

    def _gate(self, v: float, exact: bool) -> Callback:
        def gate() -> None:
            self.engine.wait_until_quiet()
            if exact and not self._still_wanted(v):
                raise Superseded(v)
            if not exact and self._exact_todo() is not None:
                raise Superseded(v)
        return gate

    def next_job(self) -> tuple[float, bool] | None:
        """(velocity, exact?) of the next rollout, or None when there is nothing to do."""
        v = self._exact_todo()
        if v is not None:
            return v, True
        for v in self._lattice:
            if self.engine.rollout(v) is None and v not in self.failed:
                return v, False
        return None

    def _run(self) -> None:
        lower_priority()
        while True:
            self._wake.wait()
            self._wake.clear()
            while (job := self.next_job()) is not None:
                v, exact = job
                try:
                    self.engine.compute(v, self._gate(v, exact))
                    self.computed.append(v)
                except Superseded:
                    continue
                except Exception as err:  # a velocity the model cannot answer: note it, keep serving
                    self.failed[v] = f"{type(err).__name__}: {err}"
                    print(f"neuraldem serve: the rollout at {v} m/s failed: {err}", file=sys.stderr)
