"""Timing a piece of work: wall and CPU seconds per repeat, medians compared, clocks injectable.

Benchmarks compare the median of several repeats, so one repeat slowed by a background process does not
move the result. Wall time is what a user waits; CPU time (`time.process_time`: every thread of this
process) is the compute an answer took, and is what compares fairly with a solver's own CPU time. Tests
inject a fake `Clock` to check the arithmetic on known numbers.
"""

from __future__ import annotations

import resource
import statistics
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, TypeVar

import torch

from neuraldem.config import checks

T = TypeVar("T")
MEASURED = "measured"


@dataclass(frozen=True)
class Sample:
    """One repeat of a piece of work."""

    wall_s: float
    cpu_s: float


@dataclass(frozen=True)
class Clock:
    """Where time comes from (a test passes fake functions)."""

    wall: Callable[[], float] = time.perf_counter
    cpu: Callable[[], float] = time.process_time


SYSTEM_CLOCK = Clock()


@dataclass
class Timing:
    """Repeats of one piece of work, and where the numbers come from (`measured`, or e.g. a manifest)."""

    samples: list[Sample]
    source: str = MEASURED
    notes: dict[str, Any] = field(default_factory=dict)

    @property
    def median(self) -> Sample:
        """Median wall and median CPU time (each over the repeats)."""
        return Sample(statistics.median(s.wall_s for s in self.samples),
                      statistics.median(s.cpu_s for s in self.samples))

    def scaled(self, factor: float, **notes: Any) -> Timing:
        """The same repeats in another unit (e.g. seconds per simulated second: factor = 1 / simulated s)."""
        checks.positive("factor", factor)
        return Timing([Sample(s.wall_s * factor, s.cpu_s * factor) for s in self.samples], self.source,
                      {**self.notes, **notes})

    def as_dict(self) -> dict[str, Any]:
        m = self.median
        return {"median_wall_s": m.wall_s, "median_cpu_s": m.cpu_s,
                "repeats": len(self.samples), "wall_s": [s.wall_s for s in self.samples],
                "cpu_s": [s.cpu_s for s in self.samples], "source": self.source, **self.notes}


def time_call(fn: Callable[[], T], repeats: int, warmup: int = 1,
              clock: Clock = SYSTEM_CLOCK) -> tuple[Timing, T]:
    """Run `fn` `warmup` times untimed (caches, lazy initialisation), then `repeats` times timed.

    Returns the timing and the result of the last call (so the work is not done once more to use it)."""
    checks.positive_int("repeats", repeats)
    checks.positive_int("warmup", warmup, allow_zero=True)
    for _ in range(warmup):
        fn()
    samples, result = [], None
    for _ in range(repeats):
        w0, c0 = clock.wall(), clock.cpu()
        result = fn()
        samples.append(Sample(clock.wall() - w0, clock.cpu() - c0))
    return Timing(samples), result  # type: ignore[return-value]


def add(*costs: Sample) -> Sample:
    """The cost of pieces of work that together make one answer (e.g. simulation + post-processing)."""
    return Sample(sum(c.wall_s for c in costs), sum(c.cpu_s for c in costs))


def ratio(numerator: float, denominator: float) -> float | None:
    """numerator / denominator, None when the denominator is not positive (a clock too coarse to see it)."""
    return numerator / denominator if denominator > 0 else None


def speed_ratio(slow: Sample, fast: Sample) -> dict[str, float | None]:
    """How many times faster `fast` is, for wall and for CPU time (pass medians: `Timing.median`)."""
    return {"wall": ratio(slow.wall_s, fast.wall_s), "cpu": ratio(slow.cpu_s, fast.cpu_s)}


def side_by_side(solver_parts: list[Timing], surrogate: Timing, question: str) -> dict[str, Any]:
    """One row of a solver-vs-surrogate table: the solver's answer (the sum of the medians of its parts, e.g.
    simulation + post-processing) against the surrogate's median, with the speed-ups."""
    slow = add(*(part.median for part in solver_parts))
    fast = surrogate.median
    speedup = speed_ratio(slow, fast)
    return {"question": question, "solver_wall_s": slow.wall_s, "solver_cpu_s": slow.cpu_s,
            "surrogate_wall_s": fast.wall_s, "surrogate_cpu_s": fast.cpu_s,
            "speedup_wall": speedup["wall"], "speedup_cpu": speedup["cpu"]}


@contextmanager
def torch_threads(n: int) -> Iterator[int]:
    """Run a block with `n` torch threads (intra-op), restoring the previous setting afterwards."""
    checks.positive_int("threads", n)
    previous = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield n
    finally:
        torch.set_num_threads(previous)


NUMBERS_LINE = "numbers in "  # what `neuraldem predict` prints once its numbers are out


def command_times(cmd: list[str], repeats: int) -> tuple[Timing, Timing]:
    """(until the numbers line is printed, until the command exits) of a `neuraldem predict` command: wall clock
    from the process start; CPU of the whole run in both (the child's CPU is not split at the numbers line)."""
    numbers, whole = [], []
    for i in range(repeats + 1):  # the first run warms the file cache and is not counted
        cpu0 = children_cpu()
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        seen = None
        for line in proc.stdout:  # type: ignore[union-attr]
            if seen is None and line.startswith(NUMBERS_LINE):
                seen = time.perf_counter() - t0
        if proc.wait() != 0 or seen is None:
            raise RuntimeError(f"{' '.join(cmd)} failed (exit {proc.returncode}) or printed no numbers")
        total, cpu = time.perf_counter() - t0, children_cpu() - cpu0
        if i:
            numbers.append(Sample(seen, cpu))
            whole.append(Sample(total, cpu))
    return (Timing(numbers, notes={"cpu": "of the whole command"}), Timing(whole))


def children_cpu() -> float:
    """User + system CPU seconds of the finished child processes so far."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime
