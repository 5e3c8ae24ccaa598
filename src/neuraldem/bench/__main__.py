"""`neuraldem bench NAME key=value ...`: run one benchmark by name; without a name, list them."""

from __future__ import annotations

import importlib
import sys

from neuraldem.cli import tool_prog
from neuraldem.errors import NeuraldemError

# benchmarks that span scenes or models; each scene adds its own (`Scene.benchmarks`). name -> ("module" with
# `main(argv) -> int`, or "module:function"; what it measures); imported only when run
SHARED = {
    "model_step": ("neuraldem.bench.model_step",
                   "forward+backward time per training step of model configs, 1 vs 2 torch threads"),
    "speed_accuracy": ("neuraldem.bench.speed_accuracy",
                       "time to answer vs error: surrogate runs and cheaper LIGGGHTS settings, Pareto front"),
    "right_sizing": ("neuraldem.bench.right_sizing",
                     "the smallest model within 10 % of the best accuracy, per task, with its speed"),
    "hopper_stability": ("neuraldem.bench.stability_maps",
                         ("hopper stability map over cone angle x sliding friction (beyond the trained range): "
                          "field surrogates, GNS, and the stored runs as the rule's control")),
    "gns_stability": ("neuraldem.gns.bench.stability",
                      "the GNS baseline's stability map on the fluidized bed (fb_stability's JSON and figure)"),
    "serve_latency": ("neuraldem.bench.serve_latency",
                      "neuraldem serve in headless Chromium: slider move to updated numbers / particles, 20 moves"),
    "cluster_cost": ("neuraldem.bench.cluster_cost",
                     "CPU-hours of paper-scale datasets (hopper at 5k / 50k / 250k particles, bed trajectories)"),
    "all": ("neuraldem.bench.suite:run_all", "the hopper benchmarks, and the fluidized bed's with fb_ckpt="),
    "render": ("neuraldem.bench.suite:render", "redraw every figure and table from the results files"),
}


def by_scene() -> dict[str, dict[str, tuple[str, str]]]:
    """Every benchmark, grouped: across scenes first, then each scene's."""
    from neuraldem.scenes import registry

    return {"across scenes and models": SHARED, **{s.kind: dict(s.benchmarks) for s in registry().values()
                                                  if s.benchmarks}}


def benchmarks() -> dict[str, tuple[str, str]]:
    return {name: entry for group in by_scene().values() for name, entry in group.items()}


def entry_point(name: str):
    """The `main(argv) -> int` of benchmark `name` (imported now)."""
    module, _, function = benchmarks()[name][0].partition(":")
    return getattr(importlib.import_module(module), function or "main")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(f"usage: {tool_prog('neuraldem.bench')} NAME key=value ...   (NAME --help for its options; "
              "fb-speed = fb_speed)")
        for group, entries in by_scene().items():
            print(f"\n{group}:")
            for name, (_, description) in entries.items():
                print(f"  {name:<18} {description}")
        return 0
    name, args = argv[0].replace("-", "_"), argv[1:]  # fb-speed and fb_speed are the same benchmark
    if name not in benchmarks():
        print(f"neuraldem: error: unknown benchmark {name!r}: choose one of {', '.join(benchmarks())}",
              file=sys.stderr)
        return 2
    if sys.argv[0].startswith("neuraldem "):  # run by `neuraldem bench`: the benchmark's usage line says so
        sys.argv[0] = f"neuraldem bench {argv[0]}"
    try:
        return entry_point(name)(args)
    except NeuraldemError as err:
        print(f"neuraldem: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
