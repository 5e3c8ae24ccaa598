"""Milliseconds per training step (forward + backward) of model configs on this machine, per thread count.

`neuraldem bench model_step [configs=[...]] [threads=[1,2]] [repeats=N]`
writes results/cluster/model_step.json.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn

from neuraldem.bench.report import command_line, machine_info, write_results
from neuraldem.cli import command_parser
from neuraldem.config import checks
from neuraldem.models.hopper_field import HopperFieldModel
from neuraldem.models.registry import build_net

NAME = "model_step"
DEFAULT_CONFIGS = ("hopper_small", "fb_small")


@dataclass(frozen=True)
class Workload:
    """One training batch: hopper nets decode `n_queries` points per sample; operators encode and decode
    `n_particles` particles and a fluid grid of `grid_shape` cells per sample."""

    batch_size: int = 8
    n_queries: int = 2048
    n_particles: int = 4096
    grid_shape: tuple[int, int, int] = (12, 1, 30)


def training_step(model: nn.Module, batch: Any) -> None:
    """One forward + backward pass with a mean-square loss summed over branches (as training does)."""
    model.zero_grad(set_to_none=True)
    out = model(**batch) if isinstance(model, HopperFieldModel) else model(batch)
    sum(v.square().mean() for v in out.values()).backward()


def example_batch(model: nn.Module, workload: Workload) -> Any:
    generator = torch.Generator().manual_seed(0)
    if isinstance(model, HopperFieldModel):
        return model.example_inputs(workload.batch_size, workload.n_queries, generator=generator)
    return model.example_inputs(workload.batch_size, workload.n_particles, workload.grid_shape,
                                generator=generator)


def time_steps(model: nn.Module, batch: Any, threads: int, repeats: int, warmup: int) -> list[float]:
    """Milliseconds of `repeats` steps after `warmup` untimed ones, with `threads` torch threads."""
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        for _ in range(warmup):
            training_step(model, batch)
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            training_step(model, batch)
            times.append((time.perf_counter() - start) * 1e3)
        return times
    finally:
        torch.set_num_threads(previous)


def run(configs: tuple[str, ...] = DEFAULT_CONFIGS, threads: tuple[int, ...] = (1, 2), repeats: int = 10,
        warmup: int = 2, workload: Workload = Workload()) -> list[dict[str, Any]]:
    """One record per (config, thread count): median/min ms per step and the per-step times."""
    checks.positive_int("repeats", repeats)
    checks.positive_int("warmup", warmup, allow_zero=True)
    records = []
    for name in configs:
        torch.manual_seed(0)
        model = build_net(name).train()
        batch = example_batch(model, workload)
        for n_threads in threads:
            times = time_steps(model, batch, checks.positive_int("threads", n_threads), repeats, warmup)
            records.append({
                "config": name,
                "net": type(model).__name__,
                "parameters": sum(p.numel() for p in model.parameters()),
                "threads": n_threads,
                "median_ms": statistics.median(times),
                "min_ms": min(times),
                "times_ms": times,
                "repeats": repeats,
                "warmup": warmup,
                "workload": asdict(workload),
            })
    return records


def main(argv: list[str]) -> int:
    parser = command_parser("neuraldem.bench model_step", __doc__, summary=True)
    parser.add_argument("--configs", nargs="+", default=list(DEFAULT_CONFIGS), help="conf/model/ names")
    parser.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--repeats", type=int, default=10, help="timed steps (median reported)")
    parser.add_argument("--warmup", type=int, default=2, help="untimed steps before timing")
    parser.add_argument("--batch-size", type=int, default=Workload.batch_size)
    parser.add_argument("--n-queries", type=int, default=Workload.n_queries, help="hopper: points per sample")
    parser.add_argument("--n-particles", type=int, default=Workload.n_particles, help="operator: per sample")
    parser.add_argument("--out", type=Path, default=None, help="default: results/cluster/model_step.json")
    args = parser.parse_args(argv)
    workload = Workload(checks.positive_int("batch_size", args.batch_size),
                        checks.positive_int("n_queries", args.n_queries),
                        checks.positive_int("n_particles", args.n_particles))
    machine = machine_info()  # before the run: the load average then is what the timings competed with
    records = run(tuple(args.configs), tuple(args.threads), args.repeats, args.warmup, workload)
    for r in records:
        print(f"{r['config']:<14} threads={r['threads']}  median {r['median_ms']:8.1f} ms/step  "
              f"(min {r['min_ms']:.1f}, {r['repeats']} repeats)")
    path = write_results(NAME, records, command=command_line(NAME, argv), path=args.out, machine=machine)
    print(f"wrote {path}")
    return 0
