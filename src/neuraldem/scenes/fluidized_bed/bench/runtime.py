"""What steps the shipped bed model fastest, and whether its answers stay the same: torch against ONNX Runtime.

    neuraldem bench fb_runtime [model=fb_small] [velocities=5] [seeds=3] [repeats=5]

The ONNX path (`models.operator_onnx`) equals torch to float32 round-off per call, not bit for bit, and a bubbling
bed is chaotic: after a few hundred steps the two rollouts are different bubbling histories. What must hold is
that the answers a user reads are the same within the rollout's own spread. So at `velocities=` inlet velocities
evenly over the trained range (no held-out run is read), each runtime answers with `seeds=` rollout seeds
(`whatif.field_answer`, the path `predict` takes), and per answer the table gives the mean |onnx - torch| at
the same seed beside the mean |torch(seed i) - torch(seed j)|, the spread of the seed alone. Time: the median
of `repeats=` answers at the middle velocity, per runtime, side by side in one run, one thread.
Writes results/fluidized_bed/speed/fb_runtime.json and .md.
"""

from __future__ import annotations

import sys
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem import pretrained
from neuraldem.bench.report import command_line, machine_at_start, resolve_out, write_report
from neuraldem.bench.timing import time_call, torch_threads
from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.config import checks

NAME = "fb_runtime"
RUNTIMES = ("torch", "onnx")
QUANTITIES = {"bed_height": ("bed height [mm]", 1000.0), "bubble_fraction": ("bubble fraction [pp]", 100.0),
              "lacey": ("Lacey index", 1.0)}


def answers(field: tuple[Any, ...], velocities: list[float], seeds: int) -> dict[str, Any]:
    """{runtime: {velocity: [summary per seed]}} of the field model's what-if answers (`field`: what
    `predict.fb_field_model` reads)."""
    from neuraldem.scenes.fluidized_bed.whatif import field_answer

    module, states, settings, window = field
    out: dict[str, Any] = {rt: {} for rt in RUNTIMES}
    for rt in RUNTIMES:
        for v in velocities:
            out[rt][f"{v:.4f}"] = [field_answer(module, states, v, settings, window, seed, runtime=rt).summary
                                   for seed in range(seeds)]
    return out


def differences(runs: dict[str, Any]) -> dict[str, dict[str, float]]:
    """Per answer: mean |onnx - torch| at the same seed, and mean |torch(i) - torch(j)| over seed pairs."""
    out = {}
    for q, (_, scale) in QUANTITIES.items():
        runtime_d, seed_d = [], []
        for v, torch_runs in runs["torch"].items():
            onnx_runs = runs["onnx"][v]
            runtime_d += [abs(o[q] - t[q]) for o, t in zip(onnx_runs, torch_runs, strict=True)]
            seed_d += [abs(a[q] - b[q]) for a, b in combinations(torch_runs, 2)]
        out[q] = {"runtime_mean_abs": scale * float(np.mean(runtime_d)),
                  "seed_mean_abs": scale * float(np.mean(seed_d)) if seed_d else float("nan")}
    return out


def times(field: tuple[Any, ...], velocity: float, repeats: int) -> dict[str, Any]:
    """Median seconds of one what-if field answer per runtime (after a warm-up, which also exports once)."""
    from neuraldem.scenes.fluidized_bed.whatif import field_answer

    module, states, settings, window = field
    out = {}
    with torch_threads(1):
        for rt in RUNTIMES:
            t, _ = time_call(lambda rt=rt: field_answer(module, states, velocity, settings, window, runtime=rt),
                             repeats, warmup=1)
            out[rt] = t.as_dict()
    out["speedup"] = out["torch"]["median_wall_s"] / out["onnx"]["median_wall_s"]
    out["steps"] = window.steps
    return out


def markdown(result: dict[str, Any]) -> str:
    t = result["times"]
    lines = [f"# What steps the bed model: torch or ONNX Runtime (model {result['model']})", "",
             f"`{result['command']}`", "",
             f"One what-if field answer ({t['steps']}-step rollout, 1 thread) at {result['timed_velocity']:.3g} m/s, "
             f"median of {t['torch']['repeats']}:", "",
             "| runtime | median wall [s] |", "|---|---|",
             *(f"| {rt} | {t[rt]['median_wall_s']:.3g} |" for rt in RUNTIMES),
             "", f"ONNX Runtime: {t['speedup']:.2f}x torch's speed.", "",
             f"Answers at {len(result['velocities'])} velocities over the trained range x {result['seeds']} rollout "
             "seeds (no held-out run read):", "",
             ("| answer | mean abs(onnx - torch), same seed | mean abs(seed i - seed j), torch | "
              "within the seed spread |"),
             "|---|---|---|---|"]
    for q, (label, _) in QUANTITIES.items():
        d = result["differences"][q]
        ok = d["runtime_mean_abs"] <= d["seed_mean_abs"] * SPREAD_MARGIN
        lines.append(f"| {label} | {d['runtime_mean_abs']:.3g} | {d['seed_mean_abs']:.3g} | "
                     f"{'yes' if ok else 'NO'} |")
    return "\n".join(lines) + "\n"


SPREAD_MARGIN = 1.5  # runtime differences within 1.5x the seed-to-seed ones count as the seed's own spread


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = doc_parser(f"neuraldem.bench {NAME}", __doc__)
    p.add_argument("--model", default=None, help="shipped bed model (default: the shipped one)")
    p.add_argument("--velocities", type=int, default=5, help="inlet velocities over the trained range")
    p.add_argument("--seeds", type=int, default=3, help="rollout seeds per velocity and runtime (>= 2)")
    p.add_argument("--repeats", type=int, default=5, help="timed answers per runtime (median)")
    p.add_argument("--out", type=Path, default=None,
                   help=f"results JSON (default results/fluidized_bed/speed/{NAME}.json)")
    args = p.parse_args(argv)
    checks.positive_int("velocities", args.velocities)
    checks.positive_int("repeats", args.repeats)
    if checks.positive_int("seeds", args.seeds) < 2:
        from neuraldem.errors import ConfigError

        raise ConfigError(f"seeds={args.seeds} is invalid: the seed spread needs two seeds or more", "e.g. seeds=3")
    from neuraldem.models.operator_onnx import resolve_runtime

    resolve_runtime("onnx")  # one line when ONNX Runtime is missing
    machine = machine_at_start()
    model = pretrained.load(args.model or pretrained.default_for("fluidized_bed"), "fluidized_bed")
    lo, hi = (float(x) for x in model.meta["trained_range"]["inlet_velocity"])
    velocities = [float(v) for v in np.linspace(lo, hi, args.velocities + 2)[1:-1]]
    from neuraldem.scenes.fluidized_bed.predict import fb_field_model

    field = fb_field_model(model, "bench")
    runs = answers(field, velocities, args.seeds)
    middle = velocities[len(velocities) // 2]
    result = {"model": model.name, "command": command_line(NAME, argv), "velocities": velocities,
              "seeds": args.seeds, "timed_velocity": middle, "times": times(field, middle, args.repeats),
              "differences": differences(runs), "answers": runs}
    write_report(NAME, result, markdown(result), command=result["command"], path=resolve_out(args.out, NAME),
                 machine=machine)
    return 0


if __name__ == "__main__":
    sys.exit(main())
