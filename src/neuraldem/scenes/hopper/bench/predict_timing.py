"""What-if answers vs LIGGGHTS: how fast `neuraldem predict hopper` answers, and how close, at random in-range points.

    neuraldem bench whatif points=5 repeats=5

- answer times (median of repeats=): the GP's answer in the process; the field model's numbers as `predict`
  computes them (the model's ONNX export loaded and queried over the answer budget, results/hopper/speed/
  query_budget.md) and over every lattice point and time beside it; the whole `neuraldem predict hopper ...`
  command (Python start and imports included) until its numbers are printed and until its pictures and ParaView
  files are written, and the GP-only command (`fields=false`);
- points= random parameter sets inside the model's trained ranges (seeded): the GP and the field model beside
  LIGGGHTS at the model's scene, each with its time, and LIGGGHTS's time over theirs. The solver runs are kept in
  <data dir>/bench/whatif/ and reused (resumable).
Writes results/hopper/whatif/whatif.{json,md}.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem import pretrained
from neuraldem.bench.report import command_line, machine_at_start, resolve_out, write_report
from neuraldem.bench.timing import command_times, time_call
from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.paths import data_dir
from neuraldem.scenes.hopper.predict import errors_vs, hopper_gp, hopper_net, predict_hopper
from neuraldem.scenes.hopper.scan import verify_hopper
from neuraldem.scenes.hopper.whatif import ANSWER_BUDGET, QueryBudget

DEFAULT_POINT = {"alpha": 45.0, "mu_s": 0.4, "mu_r": 0.1}
def random_points(ranges: dict[str, list[float]], n: int, seed: int) -> list[dict[str, float]]:
    rng = np.random.default_rng(seed)
    return [{k: round(float(rng.uniform(lo, hi)), 3) for k, (lo, hi) in ranges.items()} for _ in range(n)]


def answer_times(model: pretrained.Pretrained, repeats: int, settings: Any) -> dict[str, Any]:
    from neuraldem.models.scalar_baselines import gp_answers
    from neuraldem.scenes.hopper.whatif import field_answer

    gp = hopper_gp(model)
    gp_t, _ = time_call(lambda: gp_answers(gp, [DEFAULT_POINT]), repeats)
    with tempfile.TemporaryDirectory() as tmp:
        numbers_t, a = time_call(lambda: predict_hopper(DEFAULT_POINT, str(model.folder), Path(tmp), True, False,
                                                        budget=ANSWER_BUDGET), repeats)
    net, meta = hopper_net(model, "auto")
    full_t, _ = time_call(lambda: field_answer(net, meta, DEFAULT_POINT, settings, budget=QueryBudget(1.0, 1)),
                          repeats)
    base = [sys.executable, "-m", "neuraldem", "predict", "hopper", *(f"{k}={v:g}" for k, v in DEFAULT_POINT.items()),
            f"model={model.folder}", f"out={data_dir() / 'bench' / 'whatif' / 'command'}"]
    to_numbers, with_pictures = command_times(base, repeats)
    gp_only, _ = command_times([*base, "fields=false"], repeats)
    return {"point": DEFAULT_POINT, "budget": ANSWER_BUDGET.as_dict(), "runtime": a["field"]["runtime"],
            "n_points": a["field"]["n_points"], "n_times": a["field"]["n_times"],
            "gp_in_process": gp_t.as_dict(), "field_numbers_in_process": numbers_t.as_dict(),
            "field_full_query_in_process": full_t.as_dict(),
            "predict_command_to_numbers": {**to_numbers.as_dict(), "command": " ".join(base[1:])},
            "predict_command_with_pictures": with_pictures.as_dict(),
            "predict_command_gp_only": gp_only.as_dict()}


def point_rows(model: pretrained.Pretrained, points: list[dict[str, float]], settings: Any) -> list[dict[str, Any]]:
    """Each point answered by the GP, by the field model as `predict` answers (its query budget) and by LIGGGHTS."""
    from neuraldem.models.scalar_baselines import gp_answers
    from neuraldem.scenes.hopper.whatif import field_answer

    gp = hopper_gp(model)
    net, meta = hopper_net(model, "auto")
    checks = verify_hopper(model, points, data_dir() / "bench" / "whatif" / model.name, settings)
    rows = []
    for point, check in zip(points, checks, strict=True):
        g = gp_answers(gp, [point])[0]
        t0 = time.perf_counter()
        f = field_answer(net, meta, point, settings, budget=ANSWER_BUDGET)
        field_s = time.perf_counter() - t0
        rows.append({"parameters": point, "liggghts": check, "gp": {"mean": g.mean, "low": g.low, "high": g.high,
                                                                   "seconds": g.seconds},
                     "field": {"summary": f.summary, "seconds": field_s}})
    return rows


def markdown(result: dict[str, Any], threshold: float) -> str:
    t = result["answer_times"]
    budget = t["budget"]

    def med(key: str, digits: int = 2) -> str:
        return f"{t[key]['median_wall_s']:.{digits}f}"

    lines = [f"# What-if answers vs LIGGGHTS (model {result['model']})", "",
             "Answer time at {} (`{}`), median of {} wall-clock runs:".format(
                 ", ".join(f"{k}={v:g}" for k, v in t["point"].items()), result["command"],
                 t["gp_in_process"]["repeats"]), "",
             "| answer | median wall [s] |", "|---|---|",
             f"| GP, in the process | {med('gp_in_process', 4)} |",
             f"| field model's numbers as `predict` computes them ({t['runtime']}; {t['n_points']} points = "
             f"{budget['query_points']:g} of the lattice, {t['n_times']} times = every {budget['time_stride']}th; "
             f"model loading included), in the process | {med('field_numbers_in_process', 3)} |",
             f"| field model over every lattice point and time, in the process | "
             f"{med('field_full_query_in_process')} |",
             f"| `neuraldem predict hopper ...`, whole command until its numbers are printed | "
             f"{med('predict_command_to_numbers')} |",
             f"| the same command until its pictures and ParaView files are written | "
             f"{med('predict_command_with_pictures')} |",
             f"| `neuraldem predict hopper ... fields=false` (GP only), whole command until its numbers are printed | "
             f"{med('predict_command_gp_only')} |", "",
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
            f"{r['liggghts']['seconds']:.0f} | {g['seconds']:.4f} | {f['seconds']:.3f} | "
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
    p.add_argument("--out", type=Path, default=None, help="results JSON (default results/hopper/whatif/whatif.json)")
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
