"""The background worker of the whole discharge: one thread per server, the newest wanted point first."""

from __future__ import annotations

import sys
import threading
from collections.abc import Hashable
from typing import Any

from neuraldem.serve.workers import Callback, SessionWants, lower_priority


class DischargeWorker(SessionWants):
    def __init__(self, engine: Any):
        super().__init__()
        self.engine = engine
        self._thread: threading.Thread | None = None
        self.computed = 0  # whole discharges finished (tests read it)

    def want(self, session: Hashable, point: Any, done: Callback) -> None:
        """Session `session` now wants the whole discharge at `point` (replacing what it wanted before)."""
        with self._lock:
            self._wanted[session] = (point, done)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="hopper-discharge", daemon=True)
                self._thread.start()
        self._wake.set()

    def _next(self) -> Any | None:
        """The most recently wanted point not computed yet; sessions whose point is done are called back."""
        return self._pending(lambda point: self.engine.discharge(point) is not None)

    def _run(self) -> None:
        lower_priority()
        while True:
            self._wake.wait()
            self._wake.clear()
            while (point := self._next()) is not None:
                try:
                    if self.engine.compute_discharge(point, lambda p=point: not self._still_wanted(p)) is not None:
                        self.computed += 1
                except Exception as err:  # a point the model cannot answer: drop it, keep serving
                    print(f"neuraldem serve: the whole discharge at {point} failed: {err}", file=sys.stderr)
                    with self._lock:
                        self._wanted = {s: w for s, w in self._wanted.items() if w[0] != point}
