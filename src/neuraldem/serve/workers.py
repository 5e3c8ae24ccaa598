"""Background work for the explorer's pages: one thread per server and page, the newest wanted item first.

Each browser session says which point it wants (only its latest); a computation nobody wants any more is
cancelled between chunks, so dragging a slider never queues seconds of stale work. Done points are cached
by the engine, and the sessions that wanted them are called back (from this thread).
"""

from __future__ import annotations

import contextlib
import sys
import threading
from collections.abc import Callable, Container, Hashable
from typing import Any

Callback = Callable[[], None]
NICE = 10  # the worker thread's niceness: a person's moves (nice 0) get the CPU first


def lower_priority() -> None:
    """Lower this thread's CPU priority (Linux schedules threads one by one; elsewhere nothing happens), so
    the seconds of background work take CPU from idle time, not from the page's answers."""
    import os

    with contextlib.suppress(AttributeError, OSError):
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), NICE)


class SessionWants:
    """What each browser session wants computed in the background (only its latest item), shared by the pages'
    workers: which items are still wanted, the newest one not done, and calling back the sessions whose item
    is done (from the worker thread)."""

    def __init__(self) -> None:
        self._wanted: dict[Hashable, tuple[Any, Callback]] = {}  # session -> (item, call when done)
        self._lock = threading.Lock()
        self._wake = threading.Event()

    def forget(self, session: Hashable) -> None:
        with self._lock:
            self._wanted.pop(session, None)

    def _still_wanted(self, item: Any) -> bool:
        with self._lock:
            return any(w == item for w, _ in self._wanted.values())

    def _pending(self, is_done: Callable[[Any], bool], skip: Container[Any] = ()) -> Any | None:
        """The newest wanted item not done (nor in `skip`); sessions whose item is done are called back."""
        with self._lock:
            wanted = list(self._wanted.items())
        todo = None
        for session, (item, done) in wanted:
            if is_done(item):
                self._finish(session, item, done)
            elif item not in skip:
                todo = item
        return todo

    def _finish(self, session: Hashable, item: Any, done: Callback) -> None:
        with self._lock:
            if self._wanted.get(session, (None,))[0] != item:
                return
            del self._wanted[session]
        try:
            done()
        except Exception as err:  # e.g. the browser tab closed meanwhile: the other sessions still get theirs
            print(f"neuraldem serve: a session's callback for {item} failed: {err}", file=sys.stderr)
