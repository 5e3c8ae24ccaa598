"""Run solver processes serially in their own folder: output capture, CPU time, timeout.

`run_process` is the shared process handling (LIGGGHTS here, OpenFOAM in `neuraldem.sim.openfoam`).
Independent runs go side by side (one per core); MPI on a 2-core machine only burns CPU.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from neuraldem.errors import SolverError, SolverInterrupted
from neuraldem.sim.liggghts import find_liggghts, solver_env

# LIGGGHTS prints its seeds check, mesh and insertion errors as "ERROR: ..." lines.
ERROR_PREFIXES = ("ERROR", "ERROR on proc")


def _die_with_parent() -> None:
    """Linux: the solver gets SIGKILL when the thread that started it dies (a killed datagen leaves no
    orphaned solver burning a core). Elsewhere a no-op."""
    try:
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


@dataclass
class SolverRun:
    returncode: int
    wall_s: float
    cpu_s: float  # user + system time of the solver process
    max_rss_mb: float
    log: str  # the LIGGGHTS log text
    workdir: Path

    @property
    def error_line(self) -> str | None:
        for line in self.log.splitlines()[::-1]:
            if line.startswith(ERROR_PREFIXES):
                return line.strip()
        return None


@dataclass
class ProcessResult:
    """How a solver process ended and what it cost."""

    returncode: int  # -9 when killed at the time limit
    wall_s: float
    cpu_s: float  # user + system time of the process (and its reaped children)
    max_rss_mb: float
    timed_out: bool


# signals that stop a healthy solver from outside (kill, Ctrl-C, hang-up, OOM killer); a solver that crashes
# by itself dies of SIGSEGV, SIGFPE, SIGABRT, ... and that is a failed run
OUTSIDE_STOP_SIGNALS = {signal.SIGTERM, signal.SIGINT, signal.SIGKILL, signal.SIGHUP}


def run_process(cmd: list[str], workdir: Path, env: dict[str, str], output: Path,
                timeout_s: float | None = None) -> ProcessResult:
    """Run one solver process in `workdir` with stdout and stderr going to `output`.

    CPU time comes from os.wait4 (the process's own rusage, unaffected by other load on the machine); past
    `timeout_s` of wall time the process is killed. The process dies with the thread that started it
    (`_die_with_parent`), so a killed driver leaves no solver behind."""
    t0 = time.perf_counter()
    timed_out = False
    with open(output, "w") as out:
        proc = subprocess.Popen(cmd, cwd=workdir, env=env, stdout=out, stderr=subprocess.STDOUT,
                                preexec_fn=_die_with_parent)
        deadline = None if timeout_s is None else t0 + timeout_s
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if deadline is not None and time.perf_counter() > deadline:
                proc.kill()
                _, status, usage = os.wait4(proc.pid, 0)
                timed_out = True
                break
            time.sleep(0.05)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if not timed_out and -proc.returncode in OUTSIDE_STOP_SIGNALS:
        name = signal.Signals(-proc.returncode).name
        raise SolverInterrupted(f"{Path(cmd[0]).name} in {workdir} was stopped by {name} from outside",
                                "the simulation is left unfinished (not failed); run the same command again "
                                "to resume it")
    return ProcessResult(returncode=proc.returncode, wall_s=time.perf_counter() - t0,
                         cpu_s=usage.ru_utime + usage.ru_stime, max_rss_mb=usage.ru_maxrss / 1024.0,
                         timed_out=timed_out)


def run_liggghts(workdir: Path, input_name: str, timeout_s: float | None = None,
                 log_name: str = "log.liggghts") -> SolverRun:
    """Run `liggghts -in input_name` in `workdir`; never raises for a failed run (the caller decides),
    only when the binary is missing. The screen goes to `screen.txt`, the log to `log_name`."""
    exe = find_liggghts()
    res = run_process([str(exe), "-in", input_name, "-log", log_name], workdir, solver_env(),
                      workdir / "screen.txt", timeout_s)
    log_path = workdir / log_name
    log = log_path.read_text(errors="replace") if log_path.exists() else ""
    if not log:  # errors before the log opens only reach the screen
        log = (workdir / "screen.txt").read_text(errors="replace")
    return SolverRun(returncode=res.returncode, wall_s=res.wall_s, cpu_s=res.cpu_s,
                     max_rss_mb=res.max_rss_mb, log=log, workdir=workdir)


def require_success(run: SolverRun, what: str) -> None:
    """Raise a SolverError naming the run folder and the solver's own error line."""
    if run.returncode != 0 or run.error_line:
        reason = run.error_line or f"exit status {run.returncode}"
        if run.returncode == -9:
            reason = "killed after the time limit"
        raise SolverError(f"{what} failed in {run.workdir}: {reason} (see {run.workdir}/log.liggghts)")
