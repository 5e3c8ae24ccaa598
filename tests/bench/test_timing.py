"""Timing arithmetic on known numbers: a fake clock is injected, so every duration is exact."""

from __future__ import annotations

import pytest
import torch

from neuraldem.bench.timing import (
    Clock,
    Sample,
    Timing,
    add,
    ratio,
    side_by_side,
    speed_ratio,
    time_call,
    torch_threads,
)
from neuraldem.errors import ConfigError


class FakeClock:
    """Wall and CPU clocks that only move when the timed work moves them (`advance`)."""

    def __init__(self) -> None:
        self.wall_now = self.cpu_now = 0.0

    def advance(self, wall: float, cpu: float) -> None:
        self.wall_now += wall
        self.cpu_now += cpu

    def clock(self) -> Clock:
        return Clock(wall=lambda: self.wall_now, cpu=lambda: self.cpu_now)


def test_time_call_measures_each_repeat_and_skips_the_warmup():
    fake = FakeClock()
    durations = iter([(9.0, 9.0), (1.0, 0.5), (3.0, 2.0), (2.0, 4.0)])  # the first call is the warm-up

    def work() -> str:
        fake.advance(*next(durations))
        return "answer"

    timing, result = time_call(work, repeats=3, warmup=1, clock=fake.clock())
    assert result == "answer"
    assert [s.wall_s for s in timing.samples] == [1.0, 3.0, 2.0]
    assert [s.cpu_s for s in timing.samples] == [0.5, 2.0, 4.0]
    assert timing.median == Sample(2.0, 2.0)  # medians taken per clock
    d = timing.as_dict()
    assert d["median_wall_s"] == 2.0 and d["repeats"] == 3 and d["source"] == "measured"


def test_speed_ratio_is_a_ratio_of_medians():
    slow = Timing([Sample(100.0, 90.0), Sample(120.0, 95.0), Sample(300.0, 99.0)])  # one slow outlier
    fast = Timing([Sample(0.1, 0.2), Sample(0.1, 0.2), Sample(0.2, 0.1)])
    assert speed_ratio(slow.median, fast.median) == {"wall": pytest.approx(1200.0), "cpu": pytest.approx(475.0)}
    assert add(Sample(1.0, 2.0), Sample(0.5, 0.25)) == Sample(1.5, 2.25)
    assert ratio(1.0, 0.0) is None  # a clock too coarse to see the work: no ratio, not infinity


def test_bad_repeats_are_config_errors():
    with pytest.raises(ConfigError, match="repeats"):
        time_call(lambda: None, repeats=0)
    with pytest.raises(ConfigError, match="warmup"):
        time_call(lambda: None, repeats=1, warmup=-1)


def test_torch_threads_restores_the_setting():
    before = torch.get_num_threads()
    with torch_threads(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before


def test_side_by_side_adds_the_solver_parts():
    sim = Timing([Sample(60.0, 50.0), Sample(62.0, 52.0), Sample(70.0, 51.0)])  # medians 62 / 51
    post = Timing([Sample(2.0, 1.0)])
    model = Timing([Sample(0.064, 0.053), Sample(0.1, 0.1), Sample(0.06, 0.05)])  # medians 0.064 / 0.053
    row = side_by_side([sim, post], model, "all particle positions")
    assert row["solver_wall_s"] == 64.0 and row["solver_cpu_s"] == 52.0
    assert row["speedup_wall"] == pytest.approx(1000.0) and row["speedup_cpu"] == pytest.approx(52.0 / 0.053)
