"""`neuraldem COMMAND ...`: one command line for everything the package does.

Two argument styles, one per kind of command:
- runs composed from the config tree take Hydra overrides (`key=value`, `-m` for sweeps, `--cfg job` to
  print the composed config): datagen, train, evaluate, rollout;
- tools that read files take flags (`--out DIR`): import, report, bench, transfer, export, doctor.
`neuraldem COMMAND --help` shows a command's own options. `python -m neuraldem.<module>` still works for each.
"""

from __future__ import annotations

import importlib
import sys

# command -> (module whose main() runs it, one line of help); a dict value is a group of subcommands
COMMANDS: dict[str, tuple[str, str] | dict[str, tuple[str, str]]] = {
    "doctor": ("neuraldem.doctor", "check solvers, torch, torch-cluster and the data dir"),
    "datagen": ("neuraldem.datagen.__main__", "run the real solvers for a dataset (data=hopper_small n_sims=200)"),
    "train": ("neuraldem.train", "train a surrogate (experiment=hopper_macro; -m for sweeps)"),
    "evaluate": ("neuraldem.evaluate", "score a checkpoint against its solver (ckpt=PATH)"),
    "predict": ("neuraldem.predict", "a what-if answer from a shipped model (hopper alpha=40 mu_s=0.3 mu_r=0.1)"),
    "scan": ("neuraldem.scan", "a design chart over two parameters (hopper alpha=0:60:31 mu_s=0.05:1:20 mu_r=0.1)"),
    "serve": ("neuraldem.serve.__main__", "the interactive explorer in your browser (http://127.0.0.1:5006/hopper)"),
    "rollout": ("neuraldem.rollout", "roll a fluidized-bed model out (ckpt=PATH velocity=1.6 steps=3000)"),
    "import": {
        "liggghts": ("neuraldem.scenes.hopper.importer", "LIGGGHTS dump files of your own hopper runs as a dataset"),
        "foam": ("neuraldem.scenes.fluidized_bed.importer",
                 "OpenFOAM DPMFoam cases of your own fluidized beds as a dataset"),
    },
    "report": {
        "dataset": ("neuraldem.eval.dataset_report", "what a generated dataset holds and what it cost"),
        "fb-dataset": ("neuraldem.scenes.fluidized_bed.dataset_report",
                       "ground-truth report of a fluidized-bed dataset"),
        "hopper-table": ("neuraldem.scenes.hopper.table", "hopper runs side by side"),
        "fb-table": ("neuraldem.scenes.fluidized_bed.table", "fluidized-bed runs and baselines side by side"),
        "refill-table": ("neuraldem.scenes.hopper_refill.table", "refilling-hopper runs side by side"),
        "fb-select": ("neuraldem.scenes.fluidized_bed.select",
                      "choose a bed checkpoint on long validation rollouts (RUN_DIR --rollout-noise 3)"),
        "fb-baselines": ("neuraldem.scenes.fluidized_bed.baselines",
                         "nearest / interpolated / constant CFD-DEM baselines"),
        "hopper-cv": ("neuraldem.scenes.hopper.cv",
                      "the hopper table cross-validated (model, constant, GP, seed floor)"),
        "occupancy": ("neuraldem.scenes.hopper.occupancy_coverage",
                      "how well the occupancy field counts hopper material"),
        "step-displacement": ("neuraldem.gns.step_displacement", "how far particles move per snapshot (GNS step)"),
        "advection-oracle": ("neuraldem.scenes.fluidized_bed.advection_oracle",
                             "mixing advection with CFD-DEM's own fields"),
        "gns-rollout": ("neuraldem.gns.rollout", "roll out and score a GNS (particle) checkpoint"),
    },
    "bench": ("neuraldem.bench.__main__", "speed / accuracy benchmarks (results written to files)"),
    "transfer": ("neuraldem.scenes.hopper.transfer", "pack / unpack compact copies of a hopper dataset"),
    "export": ("neuraldem.export.__main__", "a dataset for GNS (npz) or LagrangeBench (HDF5): export gns DATASET OUT"),
}


def usage(group: dict[str, tuple[str, str] | dict[str, tuple[str, str]]], prefix: str) -> str:
    lines = [f"usage: {prefix} COMMAND [args]   ({prefix} COMMAND --help for its options)", "", "commands:"]
    for name, entry in group.items():
        text = entry[1] if isinstance(entry, tuple) else "; ".join(entry)
        lines.append(f"  {name:<18} {text}")
    return "\n".join(lines)


def resolve(argv: list[str]) -> tuple[str, str, list[str]] | str:
    """(program name, module, its arguments) for a command line, or the text to print instead."""
    group, prefix = COMMANDS, "neuraldem"
    while True:
        if not argv or argv[0] in ("-h", "--help"):
            return usage(group, prefix)
        name, argv = argv[0], argv[1:]
        entry = group.get(name) or group.get(name.replace("_", "-"))
        if entry is None:
            return f"{prefix}: error: unknown command {name!r}: choose from {', '.join(group)}"
        prefix = f"{prefix} {name}"
        if isinstance(entry, tuple):
            return prefix, entry[0], argv
        group = entry


def main(argv: list[str] | None = None) -> int:
    resolved = resolve(sys.argv[1:] if argv is None else list(argv))
    if isinstance(resolved, str):
        failed = " error: " in resolved.splitlines()[0]
        print(resolved, file=sys.stderr if failed else sys.stdout)
        return 2 if failed else 0
    prog, module, args = resolved
    sys.argv = [prog, *args]  # Hydra and argparse read the command line from here
    result = importlib.import_module(module).main()
    return result if isinstance(result, int) else 0


if __name__ == "__main__":
    sys.exit(main())
