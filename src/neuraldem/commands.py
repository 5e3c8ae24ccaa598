"""Which `neuraldem VERB [OBJECT]` command runs a tool module (docs/cli.md).

Usage lines, error messages and the command lines recorded with results name the command a user types,
`neuraldem report hopper-cv ...`, also when the tool was started as `python -m neuraldem.scenes.hopper.analysis.cv`.
The scenes' own tools (reports, importer, what-if, scan, release) are found in the scene registry, so a plug-in
scene's tools are named by their commands too. A module that no verb runs keeps `python -m <module>`.
"""

from __future__ import annotations

# tool module -> the command that runs it (`neuraldem.X.__main__` counts as `neuraldem.X`)
VERB_MODULES: dict[str, str] = {
    "neuraldem.doctor": "doctor",
    "neuraldem.datagen": "datagen",
    "neuraldem.train": "train",
    "neuraldem.evaluate": "evaluate",
    "neuraldem.rollout": "evaluate rollout",
    "neuraldem.release": "release",
    "neuraldem.predict": "predict",
    "neuraldem.scan": "scan",
    "neuraldem.serve": "serve",
    "neuraldem.bench": "bench",
    "neuraldem.export": "export",
}

# reports that span scenes (`neuraldem report NAME`); each scene adds its own (`Scene.reports`)
SHARED_REPORTS: dict[str, tuple[str, str]] = {
    "dataset": ("neuraldem.eval.dataset_report", "what a generated dataset holds and what it cost"),
    "step-displacement": ("neuraldem.gns.step_displacement", "how far particles move per snapshot (GNS step)"),
    "gns-rollout": ("neuraldem.gns.rollout", "roll out and score a GNS (particle) checkpoint"),
}


def scene_commands() -> dict[str, str]:
    """module -> command of every tool a scene holds (its reports, importer, what-if, scan, release, exports)."""
    from neuraldem.errors import NeuraldemError
    from neuraldem.scenes import registry

    out = {module: f"report {name}" for name, (module, _) in SHARED_REPORTS.items()}
    try:
        scenes = list(registry().values())
    except NeuraldemError:  # a broken plug-in is reported by the command that needs it, not while naming one
        scenes = []
    for s in scenes:
        out |= {module.partition(":")[0]: f"report {name}" for name, (module, _) in s.reports.items()}
        out |= {module.partition(":")[0]: f"bench {name}" for name, (module, _) in s.benchmarks.items()}
        out |= {module: "export" for module, _ in s.exports.values()}
        if s.importer is not None:
            out[s.importer[1]] = f"import {s.importer[0]}"
        if s.whatif:
            out[s.whatif] = f"predict {s.kind}"
        if s.scan:
            out[s.scan] = f"scan {s.kind}"
        if s.release:
            out[s.release] = "release"
    return out


def command_of(module: str) -> str | None:
    """`neuraldem VERB [OBJECT]` for a tool module (`neuraldem.bench fb_speed`, a module and the object it
    runs, gives `neuraldem bench fb_speed`), or None when no verb runs it."""
    name, _, obj = module.partition(" ")
    name = name.removesuffix(".__main__")
    verb = VERB_MODULES.get(name)
    if verb is None:
        verb = scene_commands().get(name)
    if verb is None:
        return None
    return " ".join(["neuraldem", verb, *([obj] if obj else [])])


def command_or_module(module: str) -> str:
    """The command that runs `module`, or `python -m <module>` where no verb runs it."""
    return command_of(module) or f"python -m {module.removesuffix('.__main__')}"
