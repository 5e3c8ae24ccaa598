"""run_process tells a solver killed from outside (unfinished: resume later) from one that crashed by
itself (a failed run) and from one stopped at the time limit."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest

from neuraldem.errors import SolverInterrupted
from neuraldem.sim.runner import run_process


def _kill_when_started(marker: Path, sig: signal.Signals) -> threading.Thread:
    def killer() -> None:
        for _ in range(200):
            if marker.exists() and marker.read_text().strip():
                os.kill(int(marker.read_text()), sig)
                return
            time.sleep(0.02)

    thread = threading.Thread(target=killer)
    thread.start()
    return thread


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL, signal.SIGINT])
def test_killed_from_outside_is_interrupted_not_failed(tmp_path: Path, sig: signal.Signals,
                                                      request: pytest.FixtureRequest):
    pid_file = tmp_path / "pid"
    # a job started in the background (`cmd &`, as CI may be) inherits SIGINT ignored, and so would the solver;
    # any Python handler here is reset to the default in the child at exec, as in an interactive session
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    request.addfinalizer(lambda: signal.signal(signal.SIGINT, previous))
    killer = _kill_when_started(pid_file, sig)
    # exec: the pid written is the sleeping process itself
    script = f"echo $$ > {pid_file}; exec sleep 30"
    with pytest.raises(SolverInterrupted, match=rf"stopped by {sig.name} from outside.*run the same command"):
        run_process(["sh", "-c", script], tmp_path, dict(os.environ), tmp_path / "out.txt")
    killer.join()


def test_a_crash_of_its_own_is_a_result_not_an_interrupt(tmp_path: Path):
    res = run_process(["sh", "-c", "kill -SEGV $$"], tmp_path, dict(os.environ), tmp_path / "out.txt")
    assert res.returncode == -signal.SIGSEGV and not res.timed_out


def test_time_limit_is_a_result_not_an_interrupt(tmp_path: Path):
    res = run_process(["sleep", "30"], tmp_path, dict(os.environ), tmp_path / "out.txt", timeout_s=0.3)
    assert res.timed_out and res.returncode == -signal.SIGKILL
