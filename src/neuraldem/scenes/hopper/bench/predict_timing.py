"""What-if answers vs LIGGGHTS: how fast `neuraldem predict` answers, and how close, at random in-range points.

    neuraldem bench whatif points=5 repeats=5

- answer times (median of repeats=): the GP's answer in the process, the field model's (every 2nd time,
  as `predict` does), and the whole `neuraldem predict hopper ... fields=false` command (Python start and
  imports included), the numbers a user waits for;
- points= random parameter sets inside the shipped model's trained ranges (seeded): the GP and the field
  model beside LIGGGHTS at the model's scene, each with its time, and LIGGGHTS's time over theirs. The solver
  runs are kept in <data dir>/bench/whatif/ and reused (resumable).
Writes results/bench/whatif.json and whatif.md.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem import pretrained
from neuraldem.bench.report import command_line, machine_at_start, resolve_out, write_report
from neuraldem.bench.timing import time_call
from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.paths import data_dir
from neuraldem.scenes.hopper.predict import errors_vs, hopper_gp, hopper_module
from neuraldem.scenes.hopper.scan import verify_hopper

DEFAULT_POINT = {"alpha": 45.0, "mu_s": 0.4, "mu_r": 0.1}


def random_points(ranges: dict[str, list[float]], n: int, seed: int) -> list[dict[str, float]]:
    rng = np.random.default_rng(seed)
    return [{k: round(float(rng.uniform(lo, hi)), 3) for k, (lo, hi) in ranges.items()} for _ in range(n)]


def answer_times(model: pretrained.Pretrained, repeats: int, settings: Any) -> dict[str, Any]:
    from neuraldem.models.scalar_baselines import gp_answers
    from neuraldem.scenes.hopper.whatif import field_answer

    gp, module = hopper_gp(model), hopper_module(model)
    gp_t, _ = time_call(lambda: gp_answers(gp, [DEFAULT_POINT]), repeats)
    field_t, _ = time_call(lambda: field_answer(module.net, module.metadata, DEFAULT_POINT, settings,
                                                time_stride=2), repeats)
    cmd = [sys.executable, "-m", "neuraldem", "predict", "hopper",
           *(f"{k}={v:g}" for k, v in DEFAULT_POINT.items()), "fields=false",
           f"out={data_dir() / 'bench' / 'whatif' / 'command'}"]

    def command() -> None:
        subprocess.run(cmd, check=True, capture_output=True)

    cmd_t, _ = time_call(command, repeats)
    return {"point": DEFAULT_POINT, "gp_in_process": gp_t.as_dict(), "field_in_process": field_t.as_dict(),
            "predict_command_no_fields": {**cmd_t.as_dict(), "command": " ".join(cmd[1:])}}


def point_rows(model: pretrained.Pretrained, points: list[dict[str, float]], settings: Any) -> list[dict[str, Any]]:
    from neuraldem.models.scalar_baselines import gp_answers
    from neuraldem.scenes.hopper.whatif import field_answer

    gp, module = hopper_gp(model), hopper_module(model)
    checks = verify_hopper(model, points, data_dir() / "bench" / "whatif" / model.name, settings)
    rows = []
    for point, check in zip(points, checks, strict=True):
        g = gp_answers(gp, [point])[0]
        t0 = time.perf_counter()
        f = field_answer(module.net, module.metadata, point, settings, time_stride=2)
        field_s = time.perf_counter() - t0
        rows.append({"parameters": point, "liggghts": check, "gp": {"mean": g.mean, "low": g.low, "high": g.high,
                                                                   "seconds": g.seconds},
                     "field": {"summary": f.summary, "seconds": field_s}})
    return rows


def markdown(result: dict[str, Any], threshold: float) -> str:
    t = result["answer_times"]
    lines = [f"# What-if answers vs LIGGGHTS (model {result['model']})", "",
             "Answer time, median of {} (`{}`):".format(t["gp_in_process"]["repeats"], result["command"]), "",
             "| answer | median wall [s] |", "|---|---|",
             f"| GP, in the process | {t['gp_in_process']['median_wall_s']:.4f} |",
             f"| field model (every 0.1 s), in the process | {t['field_in_process']['median_wall_s']:.2f} |",
             f"| `neuraldem predict hopper ... fields=false`, whole command | "
             f"{t['predict_command_no_fields']['median_wall_s']:.2f} |", "",
             "Random points inside the trained ranges (seeded), each answered three ways:", "",
             "| point | t95 LIGGGHTS [s] | t95 GP [95 %] | t95 field | outflow LIGGGHTS / GP / field [%/s] | "
             "residual LIGGGHTS / GP / field [%] | regime LIGGGHTS / GP / field | LIGGGHTS [s] | GP [s] | "
             "field [s] | LIGGGHTS / GP | LIGGGHTS / field |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    errs = []
    for r in result["points"]:
        m, g, f = r["liggghts"]["metrics"], r["gp"], r["field"]
        if not m:
            lines.append(f"| {r['parameters']} | {r['liggghts']['status']}: {r['liggghts']['reason']} |")
            continue

        def reg(v: float) -> str:
            return "mass" if v > threshold else "funnel"

        lines.append(
            f"| {', '.join(f'{k}={v:g}' for k, v in r['parameters'].items())} | {m['drainage_t95']:.2f} | "
            f"{g['mean']['drainage_t95']:.2f} [{g['low']['drainage_t95']:.2f}, {g['high']['drainage_t95']:.2f}] | "
            f"{f['summary']['drainage_t95']:.2f} | {100 * m['outflow_rate']:.1f} / "
            f"{100 * g['mean']['outflow_rate']:.1f} / {100 * f['summary']['outflow_rate']:.1f} | "
            f"{100 * m['residual_fraction']:.1f} / {100 * g['mean']['residual_fraction']:.1f} / "
            f"{100 * f['summary']['residual_fraction']:.1f} | {reg(m['mass_flow_index'])} / "
            f"{reg(g['mean']['mass_flow_index'])} / {reg(f['summary']['mass_flow_index'])} | "
            f"{r['liggghts']['seconds']:.0f} | {g['seconds']:.4f} | {f['seconds']:.1f} | "
            f"{r['liggghts']['seconds'] / g['seconds']:.0f}x | {r['liggghts']['seconds'] / f['seconds']:.0f}x |")
        errs.append((errors_vs(g["mean"], m, threshold), errors_vs(f["summary"], m, threshold)))
    lines += ["", "Errors against LIGGGHTS, point by point (GP; field model):", ""]
    lines += [f"- {a}; {b}" for a, b in errs]
    return "\n".join(lines) + "\n"


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings

    argv = sys.argv[1:] if argv is None else argv
    p = doc_parser("neuraldem.bench whatif", __doc__)
    p.add_argument("--model", default=None, help="shipped hopper model (default: the shipped one)")
    p.add_argument("--points", type=int, default=5, help="random in-range points checked with LIGGGHTS")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--out", type=Path, default=None, help="results JSON (default results/bench/whatif.json)")
    args = p.parse_args(argv)
    machine = machine_at_start()
    model = pretrained.load(args.model or pretrained.default_for("hopper"), "hopper")
    settings = HopperMetricSettings.from_config(model.meta["metric_settings"], "meta")
    points = random_points(model.meta["trained_range"], args.points, args.seed)
    result = {"model": model.name, "command": command_line("whatif", argv),
              "answer_times": answer_times(model, args.repeats, settings),
              "points": point_rows(model, points, settings)}
    out = resolve_out(args.out, "whatif")
    write_report("whatif", result, markdown(result, settings.mass_flow_threshold), command=result["command"],
                 path=out, machine=machine)
    return 0


if __name__ == "__main__":
    sys.exit(main())
