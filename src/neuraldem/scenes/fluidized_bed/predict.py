"""The fluidized bed's what-if: `neuraldem predict fluidized_bed inlet_velocity=1.8 [verify=true]` (the
`neuraldem predict` command (`neuraldem.predict`) parses and dispatches; this module answers and prints).

Three answers (`scenes/fluidized_bed/whatif.py`: mean bed height, mean bubble fraction, Lacey index after 1 s,
over the training trajectories' 3 s): from the scalar GP with its 95 % interval, in milliseconds; from a
rollout of the field model (a few seconds), which also gives the curves, an animation of the solid fraction and
mixing, and ParaView files; with `verify=true` from DPMFoam at the same velocity (minutes). Each model's errors on
its held-out CFD-DEM runs are printed beside CFD-DEM's own spread from another packing, so the user sees which
answer to trust (results/fluidized_bed/README.md, "Whatif": on fb_small the GP is about as close as that spread,
the field model 1.2 - 2.3x further).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem import pretrained
from neuraldem.data.schema import atomic_write_json
from neuraldem.models.onnx_runtime import RUNTIMES, check_threads
from neuraldem.pretrained.trust import ErrorKey, trust_label, trust_reasons, trusted
from neuraldem.scenes.parameters import range_warnings

# how each answer's validated error is recorded in meta.json `test_errors` (which answer to trust, per quantity)
ERROR_KEYS = {"bed_height": ErrorKey("bed_height_mae_mm", " mm"),
              "bubble_fraction": ErrorKey("bubble_fraction_mae_pp", " pp"), "lacey": ErrorKey("lacey_mae")}


def add_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the field model's rollout (and of DPMFoam's packing with verify=true)")
    p.add_argument("--runtime", choices=("auto", *RUNTIMES), default="auto",
                   help="what steps the field model: onnx (ONNX Runtime, exported once per model; equal to torch "
                        "to round-off), torch, or auto (onnx when the runtime is installed)")
    p.add_argument("--threads", type=int, default=1,
                   help="threads of the field model's rollout (default 1: the fastest on a 2-core CPU)")


def answer(point: dict[str, float], model_name: str, out: Path, args: argparse.Namespace) -> dict[str, Any]:
    check_threads(args.threads)
    return predict_fb(point, model_name, out, args.fields, args.verify, args.seed, args.runtime, args.threads,
                      pictures=False)


def follow_up(answer: dict[str, Any], out: Path, args: argparse.Namespace) -> list[Path]:
    """After the numbers are printed: the curves, the animation and the ParaView files of the answer just given
    (kept from `answer`, not rolled out again); answer.json then names them."""
    pending = _PENDING.pop(out.resolve(), None)
    if pending is None:
        return []
    files = pending.draw(answer, out)
    atomic_write_json(out / "answer.json", answer)
    return files


def fb_window(model: pretrained.Pretrained) -> Any:
    from neuraldem.scenes.fluidized_bed.whatif import AnswerWindow

    return AnswerWindow.from_dict(model.meta["answer_window"])


def fb_settings(model: pretrained.Pretrained) -> Any:
    from neuraldem.scenes.fluidized_bed.analysis.metric_settings import BedMetricSettings

    return BedMetricSettings.from_config(model.meta["metric_settings"], f"{model.name} metric_settings")


def fb_field_model(model: pretrained.Pretrained, purpose: str) -> tuple[Any, Any, Any, Any]:
    """What `whatif.field_answer` takes from a shipped model: the parts of its field model a rollout reads (no
    Lightning import: `surrogate.step_model`), its first states, metric settings and answer window (read once;
    the benchmarks and the explorer answer many times from them)."""
    from neuraldem.eval.checkpoints import read_checkpoint
    from neuraldem.scenes.fluidized_bed.surrogate.step_model import read_step_model
    from neuraldem.scenes.fluidized_bed.whatif import InitialStates

    step_model = read_step_model(read_checkpoint(model.file("field")), "cpu", purpose)
    return step_model, InitialStates.load_npz(model.file("states")), fb_settings(model), fb_window(model)


def predict_fb(point: dict[str, float], model_name: str, out: Path, fields: bool, verify: bool,
               seed: int = 0, runtime: str = "auto", threads: int = 1, pictures: bool = True) -> dict[str, Any]:
    """The answers, written to out/answer.json. `pictures`: draw the curves, animation and ParaView files now;
    False leaves them to `follow_up` (the command prints the numbers first)."""
    from neuraldem.models.scalar_baselines import gp_answers
    from neuraldem.scenes.fluidized_bed.whatif import check_fluidized, load_gp

    model = pretrained.load(model_name, "fluidized_bed")
    check_fluidized(model.meta["scene"], point["inlet_velocity"])
    window = fb_window(model)
    a = gp_answers(load_gp(model.file("gp")), [point])[0]
    stored = {k: v for k, v in model.meta.get("test_errors", {}).items() if k != "runs"}
    answer: dict[str, Any] = {
        "scene": "fb", "model": model.name, "parameters": point, "answer_window": window.as_dict(),
        "gp": {"mean": a.mean, "low": a.low, "high": a.high, "seconds": a.seconds, "extrapolation": a.extrapolation},
        "stored_test_errors": stored,
    }
    warnings = range_warnings(a.extrapolation, "GP", model.meta.get("asked_range"))
    out.mkdir(parents=True, exist_ok=True)
    pending = _Pictures(f"{model.name}: inlet velocity {point['inlet_velocity']:g} m/s")
    settings = fb_settings(model) if fields or verify else None
    if fields:
        answer["field"], pending.field, pending.grid = fb_fields(model, point["inlet_velocity"], settings, window,
                                                                 seed, runtime, threads)
        pending.series["field model"] = pending.field.curves.as_series()
        warnings += range_warnings(answer["field"]["extrapolation"], "field model",
                                   model.meta.get("asked_range"))
    if verify:
        answer["dpmfoam"], curves = fb_verify(model, point["inlet_velocity"], settings, window, out, seed)
        if curves is not None:
            pending.series["DPMFoam"] = curves.as_series()
    answer["recommended"], answer["warnings"] = trusted(model.meta, point, bool(a.extrapolation), ERROR_KEYS,
                                                        warnings)
    if pictures:
        pending.draw(answer, out)
    else:
        _PENDING[out.resolve()] = pending
    atomic_write_json(out / "answer.json", answer)
    return answer


class _Pictures:
    """What the pictures of one answer are drawn from: the curves of each answer that has them and the field
    model's rollout."""

    def __init__(self, title: str):
        self.title = title
        self.series: dict[str, Any] = {}
        self.field: Any = None  # whatif.FieldAnswer
        self.grid: Any = None  # its BoxGrid

    def draw(self, answer: dict[str, Any], out: Path) -> list[Path]:
        """Draw them into `out`; answer["field"]["files"] names them."""
        files = []
        if self.series:
            from neuraldem.scenes.fluidized_bed.analysis.plots import plot_curves

            plot_curves(self.series, out / "curves.png", self.title)
            files.append(out / "curves.png")
        if self.field is not None:
            from neuraldem.scenes.fluidized_bed.analysis.plots import animate_fields
            from neuraldem.scenes.fluidized_bed.surrogate.rollout_run import write_rollout_vtk

            f, g = self.field, self.grid
            velocity = answer["parameters"]["inlet_velocity"]
            gif = animate_fields(f.rollout.times, f.rollout.solid_fraction, f.rollout.mixing,
                                 (g.lo[0], g.hi[0], g.lo[2], g.hi[2]), out / "animation.gif",
                                 f"field model, {velocity:g} m/s")
            vtk = write_rollout_vtk(out / "vtk", "bed_predicted", f.rollout, g)
            answer["field"]["files"] = {"animation": str(gif), "vtk": str(vtk[0].parent)}
            files += [Path(gif), *vtk]
        return files


_PENDING: dict[Path, _Pictures] = {}  # answers whose pictures follow the printed numbers, by output folder


def fb_fields(model: pretrained.Pretrained, velocity: float, settings: Any, window: Any, seed: int,
              runtime: str = "auto", threads: int = 1) -> tuple[dict[str, Any], Any, Any]:
    """The field model's rollout over the answer window: its answers, and the `whatif.FieldAnswer` and grid the
    pictures are drawn from."""
    from neuraldem.models.modules import compiled

    compiled.warm_up_in_background()  # the rollout's compiled numerics, while torch and the model load
    from neuraldem.scenes.fluidized_bed.whatif import field_answer

    step_model, states, _, _ = fb_field_model(model, "predict")
    f = field_answer(step_model, states, velocity, settings, window, seed, runtime=runtime, threads=threads)
    return {"summary": f.summary, "seconds": f.seconds, "runtime": f.runtime, "start": f.start,
            "extrapolation": f.extrapolation,
            "diverged_at": f.rollout.diverged_at, "steps": f.rollout.steps_done}, f, states.grid


def fb_verify(model: pretrained.Pretrained, velocity: float, settings: Any, window: Any, out: Path,
              seed: int) -> tuple[dict[str, Any], Any]:
    """DPMFoam at the same velocity; a finished check for the same inputs is read back (rerun at no cost)."""
    from neuraldem.scenes.fluidized_bed.whatif import START_SNAPSHOT, dpmfoam_answer, file_answers

    done = out / "dpmfoam.json"
    stamp = {"inlet_velocity": velocity, "scene": model.meta["scene"], "answer_window": window.as_dict(), "seed": seed}
    if done.is_file():
        kept = json.loads(done.read_text())
        if kept.get("stamp") == stamp and kept["answer"].get("file") and Path(kept["answer"]["file"]).is_file():
            print(f"DPMFoam answer read back from {done} (delete it to rerun the solver)", file=sys.stderr)
            return kept["answer"], file_answers(Path(kept["answer"]["file"]), settings, window)[1]
    scene = model.meta["scene"]["fluidized_bed"]
    print(f"running DPMFoam ({scene['n_particles']} particles, {scene['spinup_time']:g} s spin-up + "
          f"{window.duration:g} s; minutes) at the same velocity ...", file=sys.stderr)
    s = dpmfoam_answer(model.meta["scene"], velocity, out / "dpmfoam", settings, window, seed)
    answer = {"status": s.status, "reason": s.reason, "answers": s.answers, "seconds": s.seconds,
              "file": str(s.file) if s.file else None, "from_snapshot": START_SNAPSHOT}
    if s.file is not None:
        atomic_write_json(done, {"stamp": stamp, "answer": answer})
    return answer, s.curves


def table(answer: dict[str, Any]) -> str:
    """The answers side by side, one line per quantity, then the stored held-out errors."""
    from neuraldem.scenes.fluidized_bed.whatif import answer_label, format_answer, quantities

    q = quantities(answer["answer_window"]["lacey_time"])
    cols = ["GP [95 % interval]"] + (["field model"] if "field" in answer else []) + \
        (["DPMFoam"] if "dpmfoam" in answer else []) + ["trust"]
    lines = [f"| quantity | {' | '.join(cols)} |", "|---|" + "---|" * len(cols)]

    def fmt(key: str, v: float) -> str:
        return format_answer(key, v, q)

    gp = answer["gp"]
    for key in q:
        row = [f"{fmt(key, gp['mean'][key])} [{fmt(key, gp['low'][key])}, {fmt(key, gp['high'][key])}]"]
        if "field" in answer:
            row.append(fmt(key, answer["field"]["summary"][key]))
        if "dpmfoam" in answer:
            row.append(fmt(key, answer["dpmfoam"]["answers"].get(key, float("nan"))))
        row.append(trust_label(answer.get("recommended", {}).get(key)))
        lines.append(f"| {answer_label(key, q)} | {' | '.join(row)} |")
    times = [f"{gp['seconds']:.3g} s"] + ([f"{answer['field']['seconds']:.3g} s"] if "field" in answer else []) + \
        ([f"{answer['dpmfoam']['seconds']:.3g} s"] if "dpmfoam" in answer else []) + [""]
    lines.append(f"| answer time | {' | '.join(times)} |")
    lines += trust_reasons(answer.get("recommended", {}), {k: answer_label(k, q) for k in q})
    if "field" in answer and answer["field"]["diverged_at"] is not None:
        lines.append(f"field model rollout diverged at step {answer['field']['diverged_at']}: no field answers")
    stored = answer.get("stored_test_errors") or {}
    if stored.get("n_test_runs"):
        parts = [f"{who} {e['bed_height_mae_mm']:.2f} mm / {e['bubble_fraction_mae_pp']:.2f} pp / "
                 f"{e['lacey_mae']:.3f}" for who, e in (("GP", stored.get("gp")),
                                                        ("field model", stored.get("field model")),
                                                        ("training mean", stored.get("constant")),
                                                        ("CFD-DEM from another packing", stored.get("seed floor")))
                 if e]
        lines += ["", f"mean absolute errors (bed height / bubble fraction / Lacey) on {stored['n_test_runs']} "
                      f"held-out CFD-DEM runs (meta.json): " + "; ".join(parts)]
    truth = (answer.get("dpmfoam") or {}).get("answers")
    if truth:
        lines.append("")
        for who, values in (("GP", gp["mean"]), ("field model", (answer.get("field") or {}).get("summary"))):
            if values:
                lines.append(f"{who} vs DPMFoam: " + ", ".join(
                    f"{q[k][0]} {q[k][2] * (values[k] - truth[k]):+.{3 if k == 'lacey' else 2}f}"
                    f"{(' ' + q[k][1]) if q[k][1] and q[k][1] != '%' else (' pp' if q[k][1] == '%' else '')}"
                    for k in q if np.isfinite(truth.get(k, np.nan))))
    return "\n".join(lines)
