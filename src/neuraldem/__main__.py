"""`neuraldem VERB [OBJECT] key=value ...`: one command line for everything the package does (docs/cli.md).

About twelve verbs, each with one example; everything else is reachable under them (`neuraldem report --help`,
`neuraldem bench --help`, `neuraldem import --help` list what each holds, by scene). Scene-specific commands come
from the scenes (`Scene.reports`, `Scene.benchmarks`, `Scene.importer`), so a plug-in scene adds its own.
Old verbs and names still work for one release and print the new spelling.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable

from neuraldem.commands import SHARED_REPORTS

# verb -> (module whose main() runs it, one line of help, an example)
VERBS: dict[str, tuple[str, str, str]] = {
    "doctor": ("neuraldem.doctor", "check solvers, torch, torch-cluster and the data dir", "neuraldem doctor"),
    "scene": ("neuraldem.scene_files", "a scene of your own: `scene new NAME from=SCENE`, `scene list`, `scene show`",
              "neuraldem scene new my_hopper from=hopper_small"),
    "datagen": ("neuraldem.datagen.__main__", "run the real solvers for a dataset (resumable)",
                "neuraldem datagen data=hopper_small n_sims=200 workers=2"),
    "train": ("neuraldem.train", "train a surrogate (Hydra; -m for sweeps)",
              "neuraldem train experiment=hopper_micro"),
    "evaluate": ("neuraldem.evaluate", "score a checkpoint against its solver; `evaluate rollout` rolls one out",
                 "neuraldem evaluate ckpt=RUN/checkpoints/last.ckpt"),
    "release": ("neuraldem.release", "a model folder from a checkpoint, for predict, scan and serve",
                "neuraldem release ckpt=RUN/checkpoints/last.ckpt name=my_hopper"),
    "predict": ("neuraldem.predict", "a what-if answer from a shipped model, in about a second",
                "neuraldem predict hopper alpha=40 mu_s=0.3 mu_r=0.1 verify=true"),
    "scan": ("neuraldem.scan", "a design chart over two parameters",
             "neuraldem scan hopper alpha=0:60:31 mu_s=0.05:1:20 mu_r=0.1"),
    "serve": ("neuraldem.serve.__main__", "the interactive explorer in your browser",
              "neuraldem serve port=5006   (then http://127.0.0.1:5006/hopper)"),
    "bench": ("neuraldem.bench.__main__", "speed / accuracy benchmarks, results written to files",
              "neuraldem bench fb_speed ckpt=RUN/checkpoints/last.ckpt"),
    "report": ("", "tables and figures of datasets, runs and studies", "neuraldem report hopper-cv dataset=DIR"),
    "import": ("", "your own solver runs as a dataset", "neuraldem import liggghts dump=DIR ..."),
    "export": ("neuraldem.export.__main__", "a dataset for GNS / LagrangeBench, or packed for moving",
               "neuraldem export gns dataset=DIR out=DIR"),
}

# old verb -> the new command line it stands for (kept one release)
OLD_VERBS: dict[str, list[str]] = {
    "rollout": ["evaluate", "rollout"],
    "transfer": ["export"],
}


def groups() -> dict[str, dict[str, tuple[str, str]]]:
    """The verbs that are groups of subcommands: name -> (module, what), the scenes' included."""
    from neuraldem.scenes import registry

    reports, imports = dict(SHARED_REPORTS), {}
    for s in registry().values():
        reports |= dict(s.reports)
        if s.importer is not None:
            name, module, what = s.importer
            imports[name] = (module, what)
    return {"report": reports, "import": imports}


def usage() -> str:
    lines = ["usage: neuraldem VERB [OBJECT] key=value ...   (neuraldem VERB --help for its options)", "",
             "verbs:"]
    for name, (_, text, example) in VERBS.items():
        lines.append(f"  {name:<9} {text}")
        lines.append(f"  {'':<9}   e.g. {example}")
    return "\n".join(lines)


def group_usage(verb: str, entries: dict[str, tuple[str, str]]) -> str:
    lines = [f"usage: neuraldem {verb} NAME key=value ...   (neuraldem {verb} NAME --help for its options)", "",
             f"{verb}s:" if verb != "import" else "formats:"]
    lines += [f"  {name:<20} {what}" for name, (_, what) in entries.items()]
    return "\n".join(lines)


def resolve(argv: list[str]) -> tuple[str, str, list[str]] | str:
    """(program name, module, its arguments) for a command line, or the text to print instead."""
    if not argv or argv[0] in ("-h", "--help"):
        return usage()
    verb, rest = argv[0], argv[1:]
    if verb in OLD_VERBS:
        new = OLD_VERBS[verb]
        print(f"neuraldem: note: `neuraldem {verb}` is `neuraldem {' '.join(new)}` now (the old verb goes in the "
              "next release)", file=sys.stderr)
        verb, rest = new[0], [*new[1:], *rest]
    if verb not in VERBS:
        return f"neuraldem: error: unknown verb {verb!r}: the verbs are {', '.join(VERBS)}"
    module = VERBS[verb][0]
    if module:
        if verb == "evaluate" and rest[:1] == ["rollout"]:
            return "neuraldem evaluate rollout", "neuraldem.rollout", rest[1:]
        return f"neuraldem {verb}", module, rest
    entries = groups()[verb]
    if not rest or rest[0] in ("-h", "--help"):
        return group_usage(verb, entries)
    name = rest[0]
    entry = entries.get(name) or entries.get(name.replace("_", "-"))
    if entry is None:
        return f"neuraldem: error: neuraldem {verb}: unknown {verb} {name!r}: choose from {', '.join(entries)}"
    return f"neuraldem {verb} {name}", entry[0], rest[1:]


def main(argv: list[str] | None = None) -> int:
    resolved = resolve(sys.argv[1:] if argv is None else list(argv))
    if isinstance(resolved, str):
        failed = " error: " in resolved.splitlines()[0]
        print(resolved, file=sys.stderr if failed else sys.stdout)
        return 2 if failed else 0
    prog, module, args = resolved
    sys.argv = [prog, *args]  # Hydra and argparse read the command line from here
    entry: Callable[[], int | None] = importlib.import_module(module).main
    result = entry()
    return result if isinstance(result, int) else 0


if __name__ == "__main__":
    sys.exit(main())
