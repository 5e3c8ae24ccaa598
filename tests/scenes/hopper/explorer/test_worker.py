"""The background worker: a session's latest point is computed and the session called back; a point nobody
wants any more is cancelled between chunks; a point that fails is dropped and the worker goes on."""

from __future__ import annotations

import threading
import time

from neuraldem.scenes.hopper.explorer.worker import DischargeWorker
from neuraldem.serve.browser import wait_for


class FakeEngine:
    """Chunks of 10 ms: 200 for point "old", 5 for the others; point "bad" fails."""

    def __init__(self):
        self.done: dict[str, str] = {}
        self.started: list[str] = []

    def discharge(self, point):
        return self.done.get(point)

    def compute_discharge(self, point, cancelled):
        self.started.append(point)
        if point == "bad":
            raise ValueError("no material")
        for _ in range(200 if point == "old" else 5):
            if cancelled():
                return None
            time.sleep(0.01)
        self.done[point] = f"answer {point}"
        return self.done[point]


def test_the_wanted_point_is_computed_and_its_session_called_back():
    engine, called = FakeEngine(), threading.Event()
    worker = DischargeWorker(engine)
    worker.want("session", "a", called.set)
    assert called.wait(5) and engine.done == {"a": "answer a"} and worker.computed == 1


def test_a_point_nobody_wants_any_more_is_cancelled():
    engine = FakeEngine()
    calls: list[str] = []
    worker = DischargeWorker(engine)
    worker.want("session", "old", lambda: calls.append("old"))
    wait_for(lambda: engine.started, 5, "the first computation")
    worker.want("session", "new", lambda: calls.append("new"))  # replaces "old"
    wait_for(lambda: "new" in engine.done, 10, "the new point")
    assert "old" not in engine.done and calls == ["new"]


def test_a_failing_point_is_dropped_and_the_worker_goes_on(capsys):
    engine, called = FakeEngine(), threading.Event()
    worker = DischargeWorker(engine)
    worker.want("one", "bad", lambda: None)
    wait_for(lambda: "bad" in engine.started, 5, "the failing point")
    worker.want("two", "good", called.set)
    assert called.wait(5) and "good" in engine.done and "bad" not in engine.done
    assert "the whole discharge at bad failed: no material" in capsys.readouterr().err
