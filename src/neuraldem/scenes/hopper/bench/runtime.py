"""What runs the hopper field model fastest on this CPU: eager torch (threads, inference mode), torch.compile, and
ONNX Runtime, on the what-if's own query shapes, with the answers compared to eager torch's.

    neuraldem bench runtime [model=hopper_small] [repeats=7]

Shapes: the right-sized answer (`whatif.ANSWER_BUDGET`: a share of the lattice's material points at every n-th
time) and one picture frame (the whole lattice at one time). Each runtime answers the same inputs; the table gives
the median seconds, the speed-up over eager torch at one thread, and the largest output difference from it (model
units). The import time of each runtime in a fresh process is measured too (what a one-off command pays before its
first answer). Writes runtime.{json,md} into results/hopper/speed/ (out=).
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem import pretrained
from neuraldem.bench.report import command_line, default_path, machine_at_start, resolve_out, write_report
from neuraldem.bench.timing import time_call
from neuraldem.cli import command_parser, report_user_errors
from neuraldem.errors import ConfigError

NAME = "runtime"
IMPORTS = {"torch": "import torch", "lightning": "import lightning", "onnxruntime": "import onnxruntime"}


def shapes(model: pretrained.Pretrained) -> dict[str, tuple[int, int]]:
    """(times, query points) of the right-sized answer and of one frame, at the default what-if point."""
    from neuraldem.scenes.hopper.predict import hopper_net
    from neuraldem.scenes.hopper.whatif import ANSWER_BUDGET, field_frames

    net, meta = hopper_net(model, "auto")
    from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings

    settings = HopperMetricSettings.from_config(model.meta.get("metric_settings", {}), "metric settings")
    frames = field_frames(net, meta, {"alpha": 45.0, "mu_s": 0.4, "mu_r": 0.1}, settings, time_stride=1)
    n_points, n_times = len(frames.points), len(frames.fields.times)
    answer = (len(range(0, n_times, ANSWER_BUDGET.time_stride)), int(round(ANSWER_BUDGET.points * n_points)))
    return {"answer": answer, "frame": (1, n_points)}


def import_seconds(statement: str, repeats: int) -> float:
    """Median wall seconds of `python -c statement` minus an empty interpreter's, in fresh processes."""
    def run(code: str) -> float:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)
        return time.perf_counter() - t0

    base = float(np.median([run("pass") for _ in range(repeats)]))
    return float(np.median([run(statement) for _ in range(repeats)])) - base


def measure_shape(net: Any, onnx_path: Path, n_times: int, n_points: int, repeats: int,
                  compile_: bool) -> list[dict[str, Any]]:
    """Every runtime on one input shape, against eager torch at one thread."""
    import torch

    from neuraldem.models.onnx_runtime import OnnxNet

    rng = np.random.default_rng(0)
    s = rng.random((n_times, net.n_scalars)).astype(np.float32)
    q = np.broadcast_to(rng.random((n_points, 3)).astype(np.float32), (n_times, n_points, 3))
    st, qt = torch.from_numpy(s), torch.from_numpy(np.ascontiguousarray(q))

    def eager(fn: Any = net) -> dict[str, np.ndarray]:
        with torch.inference_mode():
            return {k: v.numpy() for k, v in fn(st, qt).items()}

    def threads2() -> tuple[Any, Any]:
        torch.set_num_threads(2)
        try:
            return time_call(eager, repeats)
        finally:
            torch.set_num_threads(1)

    def compiled() -> tuple[Any, Any]:
        try:
            fn = torch.compile(net)
            t0 = time.perf_counter()
            eager(fn)  # the compilation
            first = time.perf_counter() - t0
            timing, out = time_call(lambda: eager(fn), repeats)
            timing.notes["first_call_s"] = first
            return timing, out
        except Exception as err:  # noqa: BLE001 - a compiler missing or failing is a result to report
            return str(err).splitlines()[0][:200], None

    def onnx(threads: int) -> tuple[Any, Any]:
        session = OnnxNet(onnx_path, threads)
        return time_call(lambda: session(scalars=s, query_pos=q), repeats)

    torch.set_num_threads(1)
    ref_timing, ref = time_call(eager, repeats)
    variants: dict[str, Any] = {"torch eager, 1 thread": lambda: (ref_timing, ref),
                                "torch eager, 2 threads": threads2}
    if compile_:
        variants["torch.compile, 1 thread"] = compiled
    variants["ONNX Runtime, 1 thread"] = lambda: onnx(1)
    variants["ONNX Runtime, 2 threads"] = lambda: onnx(2)
    rows: list[dict[str, Any]] = []
    for label, measure in variants.items():
        timing, out = measure()
        if isinstance(timing, str):
            rows.append({"runtime": label, "failed": timing})
            continue
        diff = max(float(np.abs(out[k] - ref[k]).max()) for k in ref)
        rows.append({"times": n_times, "points": n_points, "runtime": label, "median_s": timing.median.wall_s,
                     "speedup": ref_timing.median.wall_s / timing.median.wall_s, "max_abs_difference": diff,
                     **timing.notes})
        print(f"{n_times} x {n_points} {label}: {timing.median.wall_s:.4f} s", file=sys.stderr)
    return rows


def run(model_name: str, repeats: int, compile_: bool) -> dict[str, Any]:
    from neuraldem.eval.checkpoints import checkpoint_net, read_checkpoint

    model = pretrained.load(model_name, "hopper")
    net = checkpoint_net(read_checkpoint(model.file("field")), "hopper", "cpu", "bench")
    rows = [{"shape": name, **row} for name, (n_times, n_points) in shapes(model).items()
            for row in measure_shape(net, model.file("onnx"), n_times, n_points, repeats, compile_)]
    imports = {name: import_seconds(code, repeats) for name, code in IMPORTS.items()}
    return {"model": model.name, "rows": rows, "import_s": imports, "repeats": repeats}


def markdown(r: dict[str, Any]) -> str:
    lines = [f"# What runs the hopper field model ({r['model']}) fastest, median of {r['repeats']}", "",
             "| shape | runtime | times x points | median [s] | speed-up vs eager torch, 1 thread | largest "
             "difference |",
             "|---|---|---|---|---|---|"]
    for row in r["rows"]:
        if "failed" in row:
            lines.append(f"| {row['shape']} | {row['runtime']} | - | failed: {row['failed']} | - | - |")
            continue
        first = f" (first call {row['first_call_s']:.1f} s)" if "first_call_s" in row else ""
        lines.append(f"| {row['shape']} | {row['runtime']}{first} | {row['times']} x {row['points']} | "
                     f"{row['median_s']:.4f} | {row['speedup']:.2f}x | {row['max_abs_difference']:.1e} |")
    lines += ["", "Import time in a fresh process (what a one-off command pays first): " + ", ".join(
        f"{k} {v:.2f} s" for k, v in r["import_s"].items()), "",
        "Regenerate: `neuraldem bench runtime`."]
    return "\n".join(lines) + "\n"


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = command_parser(f"neuraldem.bench {NAME}", __doc__)
    p.add_argument("--model", default="hopper_small", help="a shipped or released hopper model with field.onnx")
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--no-compile", dest="compile", action="store_false", help="leave torch.compile out")
    p.add_argument("--out", type=Path, default=None, help=f"JSON file or folder (default {default_path(NAME)})")
    args = p.parse_args(argv)
    if args.repeats < 3:
        raise ConfigError(f"repeats={args.repeats} is invalid: give at least 3 (the median of several runs)")
    machine = machine_at_start()
    result = run(args.model, args.repeats, args.compile)
    write_report(NAME, result, markdown(result), command=command_line(NAME, argv or sys.argv[1:]),
                 path=resolve_out(args.out, NAME), machine=machine)
    return 0


if __name__ == "__main__":
    sys.exit(main())
