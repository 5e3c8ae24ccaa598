"""`neuraldem predict hopper alpha=40 mu_s=0.3 mu_r=0.1 [verify=true] [fields=false]`: the hopper's what-if.

Drainage time (t95 and the 1 % rule), residual, outflow and the flow regime, each from the scalar Gaussian process
with its 95 % interval (milliseconds) and from the field model (read off its predicted fields, the way DEM runs
are scored; seconds); the stripes plot of the initial height layers over time and the predicted particles as a
ParaView time series. `verify=true` runs LIGGGHTS at the model's scene and prints both answers and both times
side by side. Values outside the trained ranges are answered with a warning that names the range.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem import pretrained
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import ConfigError
from neuraldem.models.onnx_runtime import RUNTIMES, check_threads, installed
from neuraldem.pretrained.trust import ErrorKey, trust_label, trust_reasons, trusted
from neuraldem.scenes.hopper.whatif import ANSWER_BUDGET
from neuraldem.scenes.parameters import range_warnings

# how each answer's validated error is recorded in meta.json `test_errors` (which answer to trust, per quantity)
ERROR_KEYS = {
    "drainage_t95": ErrorKey("drainage_t95_pct_of_mean", " %"),
    "drainage_time": ErrorKey("drainage_mae_pct_of_mean", " %"),
    "residual_fraction": ErrorKey("residual_mae_pp", " pp"),
    "outflow_rate": ErrorKey("outflow_rel_err_pct", " %"),
    "mass_flow_index": ErrorKey("flow_regime_accuracy", " share of regimes right", higher_is_better=True),
}


def add_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--time-stride", type=int, default=2,
                   help="the fields in the stripes plot and ParaView files: every Nth time of the 0.05 s grid "
                        "(default 2: every 0.1 s)")
    p.add_argument("--query-points", type=float, default=ANSWER_BUDGET.points,
                   help="the field model's numbers: the share of the lattice's material points queried (default "
                        f"{ANSWER_BUDGET.points:g}, chosen in results/hopper/speed/query_budget.md; 1 = every one)")
    p.add_argument("--answer-stride", type=int, default=ANSWER_BUDGET.time_stride,
                   help=f"the field model's numbers: every Nth time (default {ANSWER_BUDGET.time_stride})")
    p.add_argument("--runtime", choices=("auto", *RUNTIMES), default="auto",
                   help="what runs the field model: onnx (ONNX Runtime, no torch import; the model's field.onnx), "
                        "torch, or auto (onnx when the model has it and the runtime is installed)")
    p.add_argument("--threads", type=int, default=1, help="threads of the field model (default 1)")


def answer(point: dict[str, float], model_name: str, out: Path, args: argparse.Namespace) -> dict[str, Any]:
    from neuraldem.scenes.hopper.whatif import QueryBudget

    if args.time_stride < 1:
        raise ConfigError(f"time_stride={args.time_stride} is invalid: must be >= 1")
    budget = QueryBudget(args.query_points, args.answer_stride)
    check_threads(args.threads)
    return predict_hopper(point, model_name, out, args.fields, args.verify, budget=budget, runtime=args.runtime,
                          threads=args.threads)


def follow_up(answer: dict[str, Any], out: Path, args: argparse.Namespace) -> list[Path]:
    """After the numbers are printed: the stripes plot and the ParaView files of the whole discharge."""
    return hopper_pictures(answer, out, args.time_stride, args.runtime, args.threads)


def hopper_gp(model: pretrained.Pretrained) -> Any:
    """The shipped scalar GP (file verified first), answered with numpy alone."""
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess

    return ArrayGaussianProcess.load_npz(model.file("gp"))


def hopper_module(model: pretrained.Pretrained) -> Any:
    """The shipped field model's LightningModule (file verified first): what training tools need."""
    from neuraldem.eval.checkpoints import read_checkpoint

    return read_checkpoint(model.file("field")).module("hopper", "cpu", "predict")


def hopper_net(model: pretrained.Pretrained, runtime: str = "auto", threads: int = 1) -> tuple[Any, dict[str, Any]]:
    """(net, metadata) of the shipped field model for an answer: its ONNX export through ONNX Runtime (no torch
    import) when `runtime` allows and the model has one, else the torch net alone (no Lightning import)."""
    has_onnx = "onnx" in model.meta.get("files", {})
    if runtime == "onnx" and not has_onnx:
        raise ConfigError(f"runtime=onnx: model {model.name} has no field.onnx",
                          f"release it again (neuraldem release hopper name={model.name} onnx_only=true) or "
                          "use runtime=torch")
    if runtime == "onnx" or (runtime == "auto" and has_onnx and installed()):
        from neuraldem.models.onnx_runtime import OnnxNet

        return OnnxNet(model.file("onnx"), threads), model.meta["field_metadata"]
    import torch

    from neuraldem.eval.checkpoints import checkpoint_net, read_checkpoint

    torch.set_num_threads(threads)
    checkpoint = read_checkpoint(model.file("field"))
    return checkpoint_net(checkpoint, "hopper", "cpu", "predict"), checkpoint.metadata



def format_value(key: str, v: float) -> str:
    from neuraldem.scenes.hopper.whatif import QUANTITIES

    label, unit, scale = QUANTITIES[key]
    return "-" if not np.isfinite(v) else f"{scale * v:.{3 if key == 'mass_flow_index' else 2}f}"


def table(answer: dict[str, Any]) -> str:
    """The answers side by side, one line per quantity."""
    from neuraldem.scenes.hopper.whatif import QUANTITIES

    cols = ["GP [95 % interval]"] + (["field model"] if "field" in answer else []) + \
        (["LIGGGHTS"] if "liggghts" in answer else []) + ["trust"]
    lines = [f"| quantity | {' | '.join(cols)} |", "|---|" + "---|" * len(cols)]
    gp = answer["gp"]
    trusted = answer.get("recommended", {})
    for key, (label, unit, _) in QUANTITIES.items():
        row = [f"{format_value(key, gp['mean'][key])} [{format_value(key, gp['low'][key])}, "
               f"{format_value(key, gp['high'][key])}]"]
        if "field" in answer:
            row.append(format_value(key, answer["field"]["summary"][key]))
        if "liggghts" in answer:
            row.append(format_value(key, answer["liggghts"]["metrics"].get(key, float("nan"))))
        row.append(trust_label(trusted.get(key)))
        lines.append(f"| {label}{f' [{unit}]' if unit else ''} | {' | '.join(row)} |")
    regimes = [answer["gp"]["regime"]] + ([answer["field"]["regime"]] if "field" in answer else []) + \
        ([answer["liggghts"]["regime"]] if "liggghts" in answer else []) + [trust_label(trusted.get("mass_flow_index"))]
    lines.append(f"| flow regime | {' | '.join(regimes)} |")
    times = [f"{answer['gp']['seconds']:.3g} s"] + \
        ([f"{answer['field']['seconds']:.3g} s"] if "field" in answer else []) + \
        ([f"{answer['liggghts']['seconds']:.3g} s"] if "liggghts" in answer else []) + [""]
    lines.append(f"| answer time | {' | '.join(times)} |")
    lines += trust_reasons(trusted, {k: v[0] for k, v in QUANTITIES.items()})
    stored = answer.get("stored_test_errors") or {}
    if stored.get("n_test_runs"):
        lines += ["", f"measured on {stored['n_test_runs']} held-out LIGGGHTS runs (meta.json): " + "; ".join(
            f"{who} t95 {e['drainage_t95_pct_of_mean']:.1f} %, residual {e['residual_mae_pp']:.2f} pp, outflow "
            f"{e['outflow_rel_err_pct']:.1f} %, regime {100 * e['flow_regime_accuracy']:.0f} % right"
            for who, e in (("GP", stored.get("gp")), ("field model", stored.get("field model"))) if e)]
    truth = (answer.get("liggghts") or {}).get("metrics")
    if truth:
        lines.append("")
        lines += [f"{who} vs LIGGGHTS: {errors_vs(values, truth)}" for who, values in
                  (("GP", answer["gp"]["mean"]), ("field model", (answer.get("field") or {}).get("summary")))
                  if values]
    return "\n".join(lines)


def errors_vs(values: dict[str, float], truth: dict[str, float], threshold: float = 0.5) -> str:
    """The errors a practitioner reads: relative for times and outflow, percentage points for the residual."""
    parts = []
    for key, label in (("drainage_t95", "t95"), ("outflow_rate", "outflow")):
        if truth.get(key):
            parts.append(f"{label} {100 * (values[key] - truth[key]) / truth[key]:+.1f} %")
    parts.append(f"residual {100 * (values['residual_fraction'] - truth['residual_fraction']):+.2f} pp")
    same = (values["mass_flow_index"] > threshold) == (truth["mass_flow_index"] > threshold)
    parts.append(f"regime {'right' if same else 'wrong'}")
    return ", ".join(parts)


def predict_hopper(point: dict[str, float], model_name: str, out: Path, fields: bool, verify: bool,
                   budget: Any = None, runtime: str = "auto", threads: int = 1) -> dict[str, Any]:
    """The numbers: the GP's, the field model's (from the queries of `budget`), LIGGGHTS's with `verify`."""
    from neuraldem.models.scalar_baselines import gp_answers
    from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings
    from neuraldem.scenes.hopper.whatif import field_answer, regime

    model = pretrained.load(model_name, "hopper")
    gp = hopper_gp(model)
    settings = HopperMetricSettings.from_config(model.meta.get("metric_settings", {}), f"{model.name} metric_settings")
    a = gp_answers(gp, [point])[0]
    answer: dict[str, Any] = {
        "scene": "hopper", "model": model.name, "model_folder": str(model.folder), "parameters": point,
        "gp": {"mean": a.mean, "low": a.low, "high": a.high, "seconds": a.seconds,
               "regime": f"{regime(a.mean['mass_flow_index'], settings)} "
                         f"({a.mean['mass_flow_index']:.2f} [{a.low['mass_flow_index']:.2f}, "
                         f"{a.high['mass_flow_index']:.2f}])",
               "extrapolation": a.extrapolation},
        "stored_test_errors": model.meta.get("test_errors", {}),
    }
    warnings = range_warnings(a.extrapolation, "GP", model.meta.get("asked_range"))
    if fields:
        t0 = time.perf_counter()
        net, meta = hopper_net(model, runtime, threads)
        f = field_answer(net, meta, point, settings, budget=budget)
        index = f.summary["mass_flow_index"]
        answer["field"] = {"summary": f.summary, "seconds": time.perf_counter() - t0, "n_points": len(f.points),
                           "n_times": len(f.fields.times), "budget": budget.as_dict() if budget else None,
                           "runtime": "onnx" if hasattr(net, "session") else "torch",
                           "regime": f"{regime(index, settings)} ({index:.2f})", "extrapolation": f.extrapolation}
        warnings += range_warnings(f.extrapolation, "field model", model.meta.get("asked_range"))
    if verify:
        answer["liggghts"], _ = hopper_verify(model.meta["scene"], point, settings, out)
    answer["recommended"], answer["warnings"] = trusted(model.meta, point, bool(a.extrapolation), ERROR_KEYS,
                                                        warnings)
    atomic_write_json(out / "answer.json", answer)
    return answer


def hopper_pictures(answer: dict[str, Any], out: Path, time_stride: int, runtime: str = "auto",
                    threads: int = 1) -> list[Path]:
    """The stripes plot (field model and LIGGGHTS side by side) and the field model's ParaView series, from the
    whole lattice at every `time_stride`-th time, answered a frame at a time (memory stays at one frame)."""
    if "field" not in answer and "liggghts" not in answer:
        return []  # the GP's numbers alone: nothing to draw (and no torch to import)
    from neuraldem.scenes.hopper.analysis.evaluation import predicted_point_series
    from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings
    from neuraldem.scenes.hopper.analysis.plots import stripe_panels
    from neuraldem.scenes.hopper.whatif import field_frames

    model = pretrained.load(answer["model_folder"], "hopper")
    settings = HopperMetricSettings.from_config(model.meta.get("metric_settings", {}), f"{model.name} metric_settings")
    panels, files = [], []
    if "field" in answer:
        net, meta = hopper_net(model, runtime, threads)
        frames = field_frames(net, meta, answer["parameters"], settings, time_stride)
        vtk = predicted_point_series(frames.points, frames.fields, out / "vtk", "hopper_predicted", 0.5,
                                     settings.n_layers)
        panels.append(("field model", frames.fields.times, frames.stripes))
        answer["field"]["vtk"] = str(vtk)
        files.append(vtk)
    kept = out / "liggghts.json"
    if "liggghts" in answer and kept.is_file():
        stripes = json.loads(kept.read_text()).get("stripes")
        if stripes:
            panels.append(("LIGGGHTS", np.array(json.loads(kept.read_text())["times"]), np.array(stripes)))
    if panels:
        stripe_panels([panels], out / "stripes.png")
        files.append(out / "stripes.png")
    atomic_write_json(out / "answer.json", answer)
    return files


def hopper_verify(scene_record: dict[str, Any], point: dict[str, float], settings: Any,
                  out: Path) -> tuple[dict[str, Any], Any]:
    from neuraldem.scenes.hopper.solver import HopperScene
    from neuraldem.scenes.hopper.whatif import liggghts_answer, regime

    done = out / "liggghts.json"  # a finished check is read back: the command can run again at no cost
    if done.is_file():
        kept = json.loads(done.read_text())
        if kept.get("parameters") == point and kept.get("scene") == scene_record["hopper"]:
            print(f"LIGGGHTS answer read back from {done} (delete it to rerun the solver)", file=sys.stderr)
            stripes = kept.get("stripes")
            return kept["answer"], (("LIGGGHTS", np.array(kept["times"]), np.array(stripes)) if stripes else None)
    scene = HopperScene.from_config(scene_record["hopper"], "model scene")
    print(f"running LIGGGHTS ({scene.n_particles} particles) on the same parameters ...", file=sys.stderr)
    s = liggghts_answer(scene, point, out / "liggghts", settings)
    index = s.metrics.get("mass_flow_index", float("nan"))
    answer = {"status": s.status, "reason": s.reason, "metrics": s.metrics, "seconds": s.seconds,
              "regime": f"{regime(index, settings)} ({index:.2f})" if s.metrics else s.status}
    atomic_write_json(done, {"parameters": point, "scene": scene_record["hopper"], "answer": answer,
                             "times": None if s.times is None else s.times.tolist(),
                             "stripes": None if s.stripes is None else s.stripes.tolist()})
    panel = ("LIGGGHTS", s.times, s.stripes) if s.stripes is not None else None
    return answer, panel
