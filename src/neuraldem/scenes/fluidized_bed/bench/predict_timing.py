"""The bed's what-if: how fast `neuraldem predict fluidized_bed` answers, and how close, where DPMFoam checked it.

    neuraldem bench whatif_fb repeats=5 [verified=[DIR,...]]

- answer times (median of repeats=): the GP's answer in the process, the field model's rollout over the
  answer window (3 s of bed time for fb_small) in the process, `neuraldem predict fluidized_bed ...` from its
  start until the numbers are printed and until its pictures are written, and the whole GP-only command
  (`fields=false`); Python start and imports included in the commands;
- verified=: output folders of `neuraldem predict fluidized_bed inlet_velocity=V verify=true` (each holds
  answer.json with the GP, field model and DPMFoam answers and times): tabled side by side with the time
  ratios. The solver runs are not repeated here (each costs minutes).
Writes results/fluidized_bed/whatif/whatif_fb.json and whatif_fb.md.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from neuraldem import pretrained
from neuraldem.bench.report import command_line, machine_at_start, resolve_out, write_report
from neuraldem.bench.timing import command_times, time_call
from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.errors import DataError
from neuraldem.paths import data_dir

DEFAULT_VELOCITY = 1.8  # [m/s] `neuraldem predict fluidized_bed`'s example


def answer_times(model: pretrained.Pretrained, repeats: int) -> dict[str, Any]:
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess, gp_answers
    from neuraldem.scenes.fluidized_bed.predict import fb_field_model
    from neuraldem.scenes.fluidized_bed.whatif import field_answer

    point = {"inlet_velocity": DEFAULT_VELOCITY}
    gp = ArrayGaussianProcess.load_npz(model.file("gp"))
    module, states, settings, window = fb_field_model(model, "bench")
    gp_t, _ = time_call(lambda: gp_answers(gp, [point]), repeats)
    field_t, _ = time_call(lambda: field_answer(module, states, DEFAULT_VELOCITY, settings, window), repeats,
                           warmup=1)  # the warm-up exports the net to ONNX once per machine
    torch_t, _ = time_call(lambda: field_answer(module, states, DEFAULT_VELOCITY, settings, window,
                                                runtime="torch"), repeats)
    base = [sys.executable, "-m", "neuraldem", "predict", "fluidized_bed", f"inlet_velocity={DEFAULT_VELOCITY:g}",
            f"model={model.folder}", f"out={data_dir() / 'bench' / 'whatif_fb' / 'command'}"]
    to_numbers, with_pictures = command_times(base, repeats)
    cmd = [*base, "fields=false"]
    _, cmd_t = command_times(cmd, repeats)  # the whole GP-only command, as its row says
    return {"point": point, "rollout_steps": window.steps, "gp_in_process": gp_t.as_dict(),
            "field_in_process": field_t.as_dict(), "field_in_process_torch": torch_t.as_dict(),
            "predict_command_no_fields": {**cmd_t.as_dict(), "command": " ".join(cmd[1:])},
            "predict_command_numbers": {**to_numbers.as_dict(), "command": " ".join(base[1:])},
            "predict_command_with_pictures": with_pictures.as_dict()}


def verified_rows(folders: list[Path]) -> list[dict[str, Any]]:
    rows = []
    for folder in folders:
        path = folder / "answer.json"
        if not path.is_file():
            raise DataError(f"{path} does not exist",
                            "run neuraldem predict fluidized_bed inlet_velocity=V verify=true out=DIR")
        a = json.loads(path.read_text())
        if "dpmfoam" not in a or "field" not in a or a["dpmfoam"].get("status") != "ok":
            raise DataError(f"{path} has no finished DPMFoam check and field answer",
                            "rerun neuraldem predict fluidized_bed ... verify=true without fields=false")
        rows.append({"inlet_velocity": a["parameters"]["inlet_velocity"], "gp": a["gp"]["mean"],
                     "gp_interval": [a["gp"]["low"], a["gp"]["high"]], "field": a["field"]["summary"],
                     "dpmfoam": a["dpmfoam"]["answers"], "seconds": {"gp": a["gp"]["seconds"],
                     "field": a["field"]["seconds"], "dpmfoam": a["dpmfoam"]["seconds"]}, "folder": str(folder)})
    return rows


def markdown(result: dict[str, Any]) -> str:
    t = result["answer_times"]
    lines = [f"# The bed's what-if (model {result['model']})", "",
             f"Answer time, median of {t['gp_in_process']['repeats']} (`{result['command']}`):", "",
             "| answer | median wall [s] |", "|---|---|",
             f"| GP, in the process | {t['gp_in_process']['median_wall_s']:.2g} |",
             f"| field model ({t['rollout_steps']}-step rollout), in the process (runtime=auto) | "
             f"{t['field_in_process']['median_wall_s']:.3g} |",
             *([f"| field model, in the process, runtime=torch | "
                f"{t['field_in_process_torch']['median_wall_s']:.3g} |"] if "field_in_process_torch" in t else []),
             *([f"| `neuraldem predict fluidized_bed ...`, from its start until the numbers are printed | "
                f"{t['predict_command_numbers']['median_wall_s']:.3g} |",
                f"| the same command until its curves, animation and ParaView files are written | "
                f"{t['predict_command_with_pictures']['median_wall_s']:.3g} |"]
               if "predict_command_numbers" in t else []),
             f"| `neuraldem predict fluidized_bed ... fields=false` (the GP alone), whole command | "
             f"{t['predict_command_no_fields']['median_wall_s']:.3g} |"]
    if result["verified"]:
        lines += ["", "Checked with DPMFoam (`neuraldem predict fluidized_bed inlet_velocity=V verify=true`):", "",
                  "| U0 [m/s] | bed height DPMFoam / GP / field [mm] | bubble fraction DPMFoam / GP / field [%] | "
                  "Lacey DPMFoam / GP / field | DPMFoam [s] | GP [s] | field [s] | DPMFoam / GP | DPMFoam / field |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for r in result["verified"]:
            d, g, f, s = r["dpmfoam"], r["gp"], r["field"], r["seconds"]
            lines.append(
                f"| {r['inlet_velocity']:g} | {1000 * d['bed_height']:.1f} / {1000 * g['bed_height']:.1f} / "
                f"{1000 * f['bed_height']:.1f} | {100 * d['bubble_fraction']:.1f} / {100 * g['bubble_fraction']:.1f}"
                f" / {100 * f['bubble_fraction']:.1f} | {d['lacey']:.3f} / {g['lacey']:.3f} / {f['lacey']:.3f} | "
                f"{s['dpmfoam']:.0f} | {s['gp']:.2g} | {s['field']:.3g} | {s['dpmfoam'] / s['gp']:.0f}x | "
                f"{s['dpmfoam'] / s['field']:.0f}x |")
    return "\n".join(lines) + "\n"


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = doc_parser("neuraldem.bench whatif_fb", __doc__)
    p.add_argument("--model", default=None, help="shipped bed model (default: the shipped one)")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--verified", type=Path, nargs="*", default=[],
                   help="output folders of predict fluidized_bed verify=true")
    p.add_argument("--out", type=Path, default=None,
                   help="results JSON (default results/fluidized_bed/whatif/whatif_fb.json)")
    args = p.parse_args(argv)
    machine = machine_at_start()
    model = pretrained.load(args.model or pretrained.default_for("fluidized_bed"), "fluidized_bed")
    result = {"model": model.name, "command": command_line("whatif_fb", argv),
              "answer_times": answer_times(model, args.repeats), "verified": verified_rows(args.verified)}
    out = resolve_out(args.out, "whatif_fb")
    write_report("whatif_fb", result, markdown(result), command=result["command"], path=out, machine=machine)
    return 0


if __name__ == "__main__":
    sys.exit(main())
