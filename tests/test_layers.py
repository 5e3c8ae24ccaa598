"""The layers of the code: no module imports one of a later layer (README, "Map of the code").

Shared layers first (solver runners, data helpers, models, the LightningModule base, evaluation helpers, bench
primitives), then the scenes (each a folder holding its solver use, store, metrics, model and evaluation), then
the GNS baseline (it reads every scene's store), then the exports (they read runs as the GNS does, and train it
from what they wrote), then what composes scenes (the charts over scenes, the commands).
Imports inside functions count too: a lazy import is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"

# (layer name, module-name prefixes); the first matching prefix (longest first) decides a module's layer
LAYERS = [
    ("base", ["neuraldem.errors", "neuraldem.paths", "neuraldem.commands", "neuraldem.machine", "neuraldem.cli",
              "neuraldem.config", "neuraldem.__init__",
              # the scene plug-in API: the Scene record, the registry and parameter tables (no scene imported)
              "neuraldem.scenes.__init__", "neuraldem.scenes.parameters"]),
    ("sim", ["neuraldem.sim"]),
    ("data", ["neuraldem.data", "neuraldem.datagen.driver", "neuraldem.datagen.records", "neuraldem.datagen.sampling",
              "neuraldem.datagen.__init__"]),
    ("models", ["neuraldem.models"]),
    ("lit", ["neuraldem.lit"]),
    ("eval", ["neuraldem.eval"]),
    ("bench primitives", ["neuraldem.bench.timing", "neuraldem.bench.pareto", "neuraldem.bench.plots",
                          "neuraldem.bench.report", "neuraldem.bench.model_step", "neuraldem.bench.choices",
                          "neuraldem.bench.__init__"]),
    ("shipped models", ["neuraldem.pretrained"]),
    ("explorer primitives", ["neuraldem.serve"]),
    ("scenes", ["neuraldem.scenes"]),
    ("gns", ["neuraldem.gns"]),
    ("export", ["neuraldem.export"]),
    ("composition", ["neuraldem.bench", "neuraldem.datagen", "neuraldem.train", "neuraldem.evaluate",
                     "neuraldem.rollout", "neuraldem.doctor", "neuraldem.__main__", "neuraldem.release",
                     "neuraldem.predict", "neuraldem.scan", "neuraldem.serve.__main__", "neuraldem.scene_files"]),
]


def layer(module: str) -> int:
    """The index in LAYERS of a module (a package counts as its `__init__`)."""
    best, rank = "", None
    for i, (_, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > len(best):
                best, rank = p, i
    if rank is None:
        raise AssertionError(f"{module} is in no layer: add it to tests/test_layers.py")
    return rank


def module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    return ".".join(parts)


def imports(path: Path) -> list[str]:
    """Every neuraldem module `path` imports, at the top or inside a function."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names if a.name.startswith("neuraldem")]
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("neuraldem"):
            # `from neuraldem.scenes.hopper import metrics` imports the module neuraldem.scenes.hopper.analysis.metrics
            for a in node.names:
                sub = f"{node.module}.{a.name}"
                out.append(sub if (SRC / (sub.replace(".", "/") + ".py")).exists() else node.module)
    return out


def as_module(name: str) -> str:
    """A package import means its `__init__`."""
    return f"{name}.__init__" if (SRC / name.replace(".", "/")).is_dir() else name


def test_layer_of_known_modules():
    assert layer("neuraldem.bench.timing") < layer("neuraldem.scenes.hopper.bench.speed") < layer(
        "neuraldem.gns.bench.points") < layer("neuraldem.bench.speed_accuracy")
    with pytest.raises(AssertionError, match="in no layer"):
        layer("neuraldem.somewhere_new")


def test_no_module_imports_a_later_layer():
    backwards = []
    for path in sorted((SRC / "neuraldem").rglob("*.py")):
        importer = module_name(path)
        for imported in imports(path):
            if layer(as_module(imported)) > layer(importer):
                backwards.append(f"{importer} ({LAYERS[layer(importer)][0]}) imports {imported} "
                                 f"({LAYERS[layer(as_module(imported))][0]})")
    assert not backwards, "imports against the layers:\n" + "\n".join(backwards)


def test_scenes_do_not_import_each_other_except_refill_from_hopper():
    """A scene is a folder of its own: only the refilling hopper builds on the hopper (same solver, same fields)."""
    allowed = {("hopper_refill", "hopper")}
    kinds = {p.name for p in (SRC / "neuraldem" / "scenes").iterdir() if (p / "__init__.py").is_file()}
    crossing = []
    for path in sorted((SRC / "neuraldem" / "scenes").glob("*/**/*.py")):
        kind = path.relative_to(SRC / "neuraldem" / "scenes").parts[0]
        for imported in imports(path):
            parts = imported.split(".")
            if (len(parts) > 2 and parts[1] == "scenes" and parts[2] in kinds and parts[2] != kind
                    and (kind, parts[2]) not in allowed):
                crossing.append(f"{module_name(path)} imports {imported}")
    assert not crossing, "\n".join(crossing)


def test_no_import_circles():
    """No module reaches itself through imports (lazy ones included): every circle names its modules."""
    graph: dict[str, set[str]] = {}
    for path in sorted((SRC / "neuraldem").rglob("*.py")):
        graph[as_module(module_name(path)) if path.name != "__init__.py" else module_name(path)] = {
            as_module(i) for i in imports(path)}
    circles, state = [], {}

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                circles.append(" -> ".join(stack[stack.index(nxt):] + [nxt]))
            elif nxt in graph and nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [])
    assert not circles, "import circles:\n" + "\n".join(circles)
