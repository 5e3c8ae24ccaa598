"""`python -m neuraldem.bench NAME [args]`: run one benchmark by name; without a name, list them."""

from __future__ import annotations

import importlib
import sys

from neuraldem.cli import tool_prog
from neuraldem.errors import NeuraldemError

# name -> ("module" with `main(argv) -> int`, or "module:function"; what it measures); imported only when run
BENCHMARKS = {
    "model_step": ("neuraldem.bench.model_step",
                   "forward+backward time per training step of model configs, 1 vs 2 torch threads"),
    "hopper_speed": ("neuraldem.scenes.hopper.bench.speed",
                     "LIGGGHTS vs the hopper surrogate on the same questions, side by side (speed-up ratios)"),
    "hopper_scaling": ("neuraldem.scenes.hopper.bench.scaling",
                       "LIGGGHTS cost vs particle count; surrogate cost vs query points and latent tokens"),
    "speed_accuracy": ("neuraldem.bench.speed_accuracy",
                       "time to answer vs error: surrogate runs and cheaper LIGGGHTS settings, Pareto front"),
    "right_sizing": ("neuraldem.bench.right_sizing",
                     "the smallest model within 10 % of the best accuracy, per task, with its speed"),
    "hopper_stability": ("neuraldem.bench.hopper_stability",
                         ("hopper stability map over cone angle x sliding friction (beyond the trained range): "
                          "field surrogates, GNS, and the stored runs as the rule's control")),
    "fb_speed": ("neuraldem.scenes.fluidized_bed.bench.speed",
                 "DPMFoam vs the fluidized-bed rollout per simulated second, side by side (speed-up ratios)"),
    "fb_speed_accuracy": ("neuraldem.scenes.fluidized_bed.bench.speed_accuracy",
                          ("fluidized bed: rollout cost vs error of time averages and mixing, surrogates and "
                           "cheaper DPMFoam; Pareto front, right-sizing")),
    "fb_stability": ("neuraldem.scenes.fluidized_bed.bench.stability",
                     "fluidized-bed stability map: steps to divergence / solid-volume drift across velocities"),
    "gns_stability": ("neuraldem.gns.bench.stability",
                      "the GNS baseline's stability map on the fluidized bed (fb_stability's JSON and figure)"),
    "whatif": ("neuraldem.bench.whatif",
               "neuraldem predict: answer times, and GP / field model vs LIGGGHTS at random in-range points"),
    "whatif_fb": ("neuraldem.bench.whatif_fb",
                  "neuraldem predict fb: answer times, and GP / field model vs DPMFoam where --verify checked"),
    "serve_latency": ("neuraldem.bench.serve_latency",
                      "neuraldem serve in headless Chromium: slider move to updated numbers / particles, 20 moves"),
    "cluster_cost": ("neuraldem.bench.cluster_cost",
                     "CPU-hours of paper-scale datasets (hopper at 5k / 50k / 250k particles, bed trajectories)"),
    "all": ("neuraldem.bench.suite:run_all", "the hopper benchmarks above, and the fluidized bed's with --fb-ckpt"),
    "render": ("neuraldem.bench.suite:render", "redraw every figure and table from the results files"),
    "seed_floor": ("neuraldem.scenes.hopper.bench.seed_floor",
                   "LIGGGHTS rerun with other packing seeds: the noise floor of every hopper quantity"),
}


def entry_point(name: str):
    """The `main(argv) -> int` of benchmark `name` (imported now)."""
    module, _, function = BENCHMARKS[name][0].partition(":")
    return getattr(importlib.import_module(module), function or "main")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(f"usage: {tool_prog('neuraldem.bench')} NAME [args]   (NAME --help for its options; "
              "fb-speed = fb_speed)"
              "\n\nbenchmarks:")
        for name, (_, description) in BENCHMARKS.items():
            print(f"  {name:<14} {description}")
        return 0
    name, args = argv[0].replace("-", "_"), argv[1:]  # fb-speed and fb_speed are the same benchmark
    if name not in BENCHMARKS:
        print(f"error: unknown benchmark {name!r}; choose one of {sorted(BENCHMARKS)}", file=sys.stderr)
        return 2
    if sys.argv[0].startswith("neuraldem "):  # run by `neuraldem bench`: the benchmark's usage line says so
        sys.argv[0] = f"neuraldem bench {argv[0]}"
    try:
        return entry_point(name)(args)
    except NeuraldemError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
