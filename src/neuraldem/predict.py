"""`neuraldem predict SCENE NAME=VALUE ...`: a what-if answer from a shipped pretrained model, in about a second.

    neuraldem predict hopper alpha=40 mu_s=0.3 mu_r=0.1            # numbers, stripes plot, ParaView files
    neuraldem predict hopper alpha=40 mu_s=0.3 mu_r=0.1 --verify   # ... and LIGGGHTS on the same parameters
    neuraldem predict hopper alpha=40 mu_s=0.3 mu_r=0.1 --no-fields  # the GP's numbers alone (fastest)
    neuraldem predict fb inlet_velocity=1.8 [--verify]             # a fluidized bed (DPMFoam for --verify)

Hopper: drainage time (t95 and the 1 % rule), residual, outflow and the flow regime, each from the scalar
Gaussian process with its 95 % interval and from the field model (read off its predicted fields, the way DEM
runs are scored); the stripes plot of the initial height layers over time and the predicted particles as a
ParaView time series. `--verify` runs LIGGGHTS at the model's scene and prints both answers and both times
side by side. Values outside the trained ranges are answered with a warning that names the range.
Fluidized bed (`fb`): mean bed height, mean bubble fraction and the Lacey index after 1 s, from the GP and from
a rollout of the field model (curves.png, animation.gif, vtk/), with their stored held-out errors beside
CFD-DEM's own spread (`neuraldem/predict_fb.py`). `--verify` runs DPMFoam (minutes).
Outputs go to --out (default <data dir>/predict/<scene>/<parameters>/): answer.json, plots, vtk/.
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
from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import ConfigError
from neuraldem.paths import data_dir
from neuraldem.scenes.hopper.solver import PARAMETER_LIMITS  # what LIGGGHTS can run at all

SCENES = {"hopper": "hopper", "fb": "fluidized_bed"}  # command-line scene name -> scene kind of its models


def named_values(items: list[str], names: list[str], scene: str, form: str) -> dict[str, str]:
    """`NAME=...` arguments as {name: text}: names of the model's inputs only, and every one of them."""
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise ConfigError(f"argument {item!r}: expected {form}, e.g. {names[0]}=30")
        if key not in names:
            raise ConfigError(f"unknown {scene} parameter {key!r}", f"the parameters are {', '.join(names)}")
        out[key] = value
    missing = [n for n in names if n not in out]
    if missing:
        raise ConfigError(f"missing {scene} parameter(s) {', '.join(missing)}",
                          f"give all of {' '.join(f'{n}=VALUE' for n in names)}")
    return out


def solver_limits(key: str) -> tuple[float, float]:
    """What the solvers can run at all for one parameter (LIGGGHTS hopper, DPMFoam bed)."""
    if key == "inlet_velocity":  # imported only for the bed: the hopper's answer stays fast
        from neuraldem.scenes.fluidized_bed.limits import VELOCITY_LIMITS

        return VELOCITY_LIMITS
    return PARAMETER_LIMITS.get(key, (-np.inf, np.inf))


def check_solver_limits(key: str, values: list[float]) -> None:
    """Values the solver cannot run at all are refused (values it can run but the model never saw are warned)."""
    lo, hi = solver_limits(key)
    if min(values) < lo or max(values) > hi:
        shown = f"={values[0]:g}" if len(values) == 1 else f" spans {min(values):g} .. {max(values):g},"
        raise ConfigError(f"parameter {key}{shown} is outside what the solver can run ({lo:g} .. {hi:g})")


def parse_point(items: list[str], names: list[str], scene: str) -> dict[str, float]:
    """`NAME=VALUE` arguments as {name: value}: every name of the model's inputs, no other."""
    out: dict[str, float] = {}
    for key, value in named_values(items, names, scene, "NAME=VALUE").items():
        try:
            out[key] = float(value)
        except ValueError:
            raise ConfigError(f"parameter {key}={value!r} is not a number") from None
        if not np.isfinite(out[key]):
            raise ConfigError(f"parameter {key}={value} is not a finite number")
        check_solver_limits(key, [out[key]])
    return {n: out[n] for n in names}


def range_warnings(extrapolation: dict[str, list[float]], who: str) -> list[str]:
    return [f"warning: {who}: {k}={v[0]:.4g} is outside the trained range {v[1]:.4g} .. {v[2]:.4g}: an "
            "extrapolation, trust it less" for k, v in extrapolation.items() if k != "query_points_outside_box"]


def default_out(scene: str, point: dict[str, float]) -> Path:
    return data_dir() / "predict" / scene / "_".join(f"{k}{v:g}" for k, v in point.items())


def hopper_gp(model: pretrained.Pretrained) -> Any:
    """The shipped scalar GP (file verified first), answered with numpy alone."""
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess

    return ArrayGaussianProcess.load_npz(model.file("gp"))


def hopper_module(model: pretrained.Pretrained) -> Any:
    """The shipped field model (file verified first); loads torch, so only when fields are asked for."""
    from neuraldem.eval.checkpoints import read_checkpoint

    return read_checkpoint(model.file("field")).module("hopper", "cpu", "predict")


def format_value(key: str, v: float) -> str:
    from neuraldem.scenes.hopper.whatif import QUANTITIES

    label, unit, scale = QUANTITIES[key]
    return "-" if not np.isfinite(v) else f"{scale * v:.{3 if key == 'mass_flow_index' else 2}f}"


def hopper_table(answer: dict[str, Any]) -> str:
    """The answers side by side, one line per quantity."""
    from neuraldem.scenes.hopper.whatif import QUANTITIES

    cols = ["GP [95 % interval]"] + (["field model"] if "field" in answer else []) + \
        (["LIGGGHTS"] if "liggghts" in answer else [])
    lines = [f"| quantity | {' | '.join(cols)} |", "|---|" + "---|" * len(cols)]
    gp = answer["gp"]
    for key, (label, unit, _) in QUANTITIES.items():
        row = [f"{format_value(key, gp['mean'][key])} [{format_value(key, gp['low'][key])}, "
               f"{format_value(key, gp['high'][key])}]"]
        if "field" in answer:
            row.append(format_value(key, answer["field"]["summary"][key]))
        if "liggghts" in answer:
            row.append(format_value(key, answer["liggghts"]["metrics"].get(key, float("nan"))))
        lines.append(f"| {label}{f' [{unit}]' if unit else ''} | {' | '.join(row)} |")
    regimes = [answer["gp"]["regime"]] + ([answer["field"]["regime"]] if "field" in answer else []) + \
        ([answer["liggghts"]["regime"]] if "liggghts" in answer else [])
    lines.append(f"| flow regime | {' | '.join(regimes)} |")
    times = [f"{answer['gp']['seconds']:.3g} s"] + \
        ([f"{answer['field']['seconds']:.3g} s"] if "field" in answer else []) + \
        ([f"{answer['liggghts']['seconds']:.3g} s"] if "liggghts" in answer else [])
    lines.append(f"| answer time | {' | '.join(times)} |")
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
                   time_stride: int = 1) -> dict[str, Any]:
    from neuraldem.models.scalar_baselines import gp_answers
    from neuraldem.scenes.hopper.metrics import HopperMetricSettings
    from neuraldem.scenes.hopper.whatif import regime

    model = pretrained.load(model_name, "hopper")
    gp = hopper_gp(model)
    settings = HopperMetricSettings.from_config(model.meta.get("metric_settings", {}), f"{model.name} metric_settings")
    a = gp_answers(gp, [point])[0]
    answer: dict[str, Any] = {
        "scene": "hopper", "model": model.name, "parameters": point,
        "gp": {"mean": a.mean, "low": a.low, "high": a.high, "seconds": a.seconds,
               "regime": f"{regime(a.mean['mass_flow_index'], settings)} "
                         f"({a.mean['mass_flow_index']:.2f} [{a.low['mass_flow_index']:.2f}, "
                         f"{a.high['mass_flow_index']:.2f}])",
               "extrapolation": a.extrapolation},
        "stored_test_errors": model.meta.get("test_errors", {}),
    }
    warnings = range_warnings(a.extrapolation, "GP")
    out.mkdir(parents=True, exist_ok=True)
    panels = []
    if fields:
        f = hopper_fields(hopper_module(model), point, settings, out, time_stride)
        answer["field"] = f.pop("answer")
        panels.append(f["panel"])
        warnings += range_warnings(answer["field"]["extrapolation"], "field model")
    if verify:
        answer["liggghts"], panel = hopper_verify(model.meta["scene"], point, settings, out)
        if panel is not None:
            panels.append(panel)
    if panels:
        from neuraldem.scenes.hopper.plots import stripe_panels

        stripe_panels([panels], out / "stripes.png")
    answer["warnings"] = warnings
    atomic_write_json(out / "answer.json", answer)
    return answer


def hopper_fields(module: Any, point: dict[str, float], settings: Any, out: Path, time_stride: int) -> dict[str, Any]:
    from neuraldem.scenes.hopper.evaluation import predicted_point_series
    from neuraldem.scenes.hopper.whatif import field_answer, regime

    f = field_answer(module.net, module.metadata, point, settings, time_stride=time_stride)
    vtk = predicted_point_series(f.points, f.fields, out / "vtk", "hopper_predicted", 0.5, settings.n_layers)
    index = f.summary["mass_flow_index"]
    return {"answer": {"summary": f.summary, "seconds": f.seconds, "n_points": len(f.points),
                       "regime": f"{regime(index, settings)} ({index:.2f})", "extrapolation": f.extrapolation,
                       "vtk": str(vtk)},
            "panel": ("field model", f.fields.times, f.stripes)}


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


def what_if_parser(module: str, doc: str | None, parameters_help: str) -> argparse.ArgumentParser:
    """The arguments `predict` and `scan` share: the scene, its parameters, the shipped model, the output folder."""
    p = doc_parser(module, doc)
    p.add_argument("scene", help=f"one of: {', '.join(SCENES)}")
    p.add_argument("parameters", nargs="*", help=parameters_help)
    p.add_argument("--model", default=None,
                   help=f"shipped model name (default: the scene's; shipped: {', '.join(pretrained.names())})")
    p.add_argument("--out", type=Path, default=None, help="output folder")
    return p


def scene_kind(scene: str) -> str:
    if scene not in SCENES:
        raise ConfigError(f"unknown scene {scene!r}", f"choose one of: {', '.join(SCENES)}")
    return SCENES[scene]


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = what_if_parser("neuraldem.predict", __doc__, "NAME=VALUE, e.g. alpha=40 mu_s=0.3 mu_r=0.1")
    p.add_argument("--verify", action="store_true", help="also run the solver and show both answers")
    p.add_argument("--no-fields", dest="fields", action="store_false", help="the GP's numbers only")
    p.add_argument("--time-stride", type=int, default=2,
                   help="hopper field model: every Nth time of the 0.05 s grid (default 2: every 0.1 s)")
    p.add_argument("--seed", type=int, default=0,
                   help="fb: seed of the field model's rollout (and of DPMFoam's packing with --verify)")
    p.add_argument("--json", action="store_true", help="print answer.json instead of the table")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    kind = scene_kind(args.scene)
    if args.time_stride < 1:
        raise ConfigError(f"--time-stride {args.time_stride} is invalid: must be >= 1")
    name = args.model or pretrained.default_for(kind)
    inputs = pretrained.load(name, kind).meta["inputs"]
    point = parse_point(args.parameters, list(inputs), args.scene)
    out = args.out or default_out(args.scene, point)
    if kind == "fluidized_bed":
        from neuraldem.predict_fb import fb_table, predict_fb

        answer = predict_fb(point, name, out, args.fields, args.verify, args.seed)
        table = fb_table
    else:
        answer = predict_hopper(point, name, out, args.fields, args.verify, args.time_stride)
        table = hopper_table
    for w in answer["warnings"]:
        print(w, file=sys.stderr)
    if args.json:
        print(json.dumps(answer, indent=1, default=float))
    else:
        print(f"{args.scene} what-if {' '.join(f'{k}={v:g}' for k, v in point.items())} (model {name}):")
        print(table(answer))
        print(f"outputs in {out} ({time.perf_counter() - t0:.2f} s in this command)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
