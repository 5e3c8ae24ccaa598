"""`neuraldem predict SCENE name=value ...`: a what-if answer from a shipped model, in about a second.

    neuraldem predict hopper alpha=40 mu_s=0.3 mu_r=0.1                 # numbers, stripes plot, ParaView files
    neuraldem predict hopper alpha=40 mu_s=0.3 mu_r=0.1 verify=true     # ... and LIGGGHTS on the same hopper
    neuraldem predict hopper alpha=40 mu_s=0.3 mu_r=0.1 fields=false    # the GP's numbers alone (fastest)
    neuraldem predict fluidized_bed inlet_velocity=1.8 [verify=true]    # a fluidized bed (DPMFoam to verify)

Every scene answers from its scalar Gaussian process (95 % intervals, milliseconds) and from its field model
(seconds), with the model's errors on its held-out runs beside them; `verify=true` runs the solver on the same
parameters and prints both answers and both times. Values the solver cannot run are refused; values outside the
trained ranges are answered with a warning that names the range (and the range datagen was asked for, where the
runs covered less). `model=` is a model's name (yours in `NEURALDEM_MODELS`, default <data dir>/models, then
the shipped ones) or a released model's folder (`neuraldem release ... out=DIR`: model=DIR/NAME). What each
scene answers is in its what-if module (`Scene.whatif`). Outputs go to `out=` (default
<data dir>/predict/<scene>/<parameters>/): answer.json, plots, vtk/.
"""

from __future__ import annotations

import importlib
import json
import sys
import time
from pathlib import Path
from types import ModuleType
from typing import Any

from neuraldem import STARTED, pretrained, scenes
from neuraldem.cli import CommandParser, command_parser, output_folder, report_user_errors
from neuraldem.errors import ConfigError
from neuraldem.paths import data_dir
from neuraldem.scenes.parameters import parse_point


def default_out(scene: str, point: dict[str, float]) -> Path:
    return data_dir() / "predict" / scene / "_".join(f"{k}{v:g}" for k, v in point.items())


def peek(argv: list[str], key: str) -> str | None:
    """The value of `key=` (or the old `--key V`) before the full parser exists (it depends on the model)."""
    for i, token in enumerate(argv):
        if token.startswith(f"{key}="):
            return token.split("=", 1)[1]
        if token == f"--{key}" and i + 1 < len(argv):
            return argv[i + 1]
    return None


def what_if(verb: str, argv: list[str], attribute: str) -> tuple[scenes.Scene, ModuleType] | str:
    """The scene named first on a `predict`/`scan` command line and its module, or the help text to print."""
    able = [s for s in scenes.registry().values() if getattr(s, attribute)]
    if not argv or argv[0] in ("-h", "--help"):
        lines = [f"usage: neuraldem {verb} SCENE name=value ... (neuraldem {verb} SCENE --help for its options)",
                 "", "scenes:"]
        lines += [f"  {' / '.join(s.names):<28} {', '.join(s.parameters.names)}" for s in able]
        return "\n".join(lines)
    chosen = scenes.by_name(argv[0])
    if not getattr(chosen, attribute):
        other = f"; or ask neuraldem predict {chosen.kind} at the values you want" if verb != "predict" else ""
        raise ConfigError(f"neuraldem {verb} has no answers for the {chosen.kind} scene",
                          f"choose one of: {', '.join(s.kind for s in able)}{other}")
    return chosen, importlib.import_module(getattr(chosen, attribute))


def what_if_parser(verb: str, scene: scenes.Scene, module: ModuleType, inputs: list[str],
                   value_help: str) -> CommandParser:
    """The options `predict` and `scan` share: the model's inputs, the model, the output folder."""
    p = command_parser(f"neuraldem.{verb} {scene.kind}", module.__doc__)
    p.prog = f"neuraldem {verb} {scene.kind}"
    for name in inputs:
        unit = scene.parameters[name].unit if name in scene.parameters else ""
        p.add_argument(f"--{name}", dest=name, default=None, metavar=value_help,
                       help=(scene.parameters[name].meaning if name in scene.parameters else "a model input")
                       + (f" [{unit}]" if unit else ""))
    p.add_argument("--model", default=None,
                   help=f"a model's name or a released model's folder (default: the first {scene.kind} model found, "
                        f"yours before the shipped one; found: {', '.join(pretrained.names())})")
    p.add_argument("--out", type=Path, default=None, help="output folder")
    return p


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    found = what_if("predict", argv, "whatif")
    if isinstance(found, str):
        print(found)
        return 0
    scene, module = found
    t0 = STARTED
    name = peek(argv[1:], "model") or pretrained.default_for(scene.kind)
    inputs = list(pretrained.load(name, scene.kind).meta["inputs"])
    p = what_if_parser("predict", scene, module, inputs, "VALUE")
    p.add_argument("--verify", action="store_true", help="also run the solver and show both answers")
    p.add_argument("--no-fields", dest="fields", action="store_false", help="the GP's numbers only")
    p.add_argument("--json", action="store_true", help="print answer.json instead of the table")
    p.add_argument("--no-pictures", dest="pictures", action="store_false",
                   help="numbers only: no plots and ParaView files after them")
    module.add_options(p)
    args = p.parse_args(argv[1:])
    given = {n: getattr(args, n) for n in inputs if getattr(args, n) is not None}
    point = parse_point(given, inputs, scene.kind, scene.parameters)
    out = output_folder(args.out or default_out(scene.kind, point))
    answer: dict[str, Any] = module.answer(point, name, out, args)
    for w in answer["warnings"]:
        print(w, file=sys.stderr)
    if args.json:
        print(json.dumps(answer, indent=1, default=float), flush=True)
    else:
        print(f"{scene.kind} what-if {' '.join(f'{k}={v:g}' for k, v in point.items())} "
              f"(model {answer.get('model', name)}):")
        print(module.table(answer))
        print(f"numbers in {time.perf_counter() - t0:.2f} s since the command started", flush=True)
    follow_up = getattr(module, "follow_up", None)  # pictures and ParaView files come after the numbers
    if follow_up is not None and args.pictures:
        files = follow_up(answer, out, args)
        if files and not args.json:
            print(f"{len(files)} picture(s) and ParaView series in {out} ({time.perf_counter() - t0:.2f} s in all)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
