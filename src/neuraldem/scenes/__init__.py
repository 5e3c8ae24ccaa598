"""Scenes are plug-ins: everything about a hopper, a refilling hopper or a fluidized bed lives in its folder.

A scene is a Python package that defines `SCENE = Scene(...)` in its `__init__.py`: its parameter table, its
datagen pipeline, how a checkpoint of it is evaluated, and the parts the generic commands dispatch to by kind
(`predict`, `scan`, the explorer page, `release`, its benchmarks, reports and importer). The commands never name
a scene; they look it up here by the `kind` a dataset manifest or checkpoint records, or by the name a user
typed (`neuraldem predict fluidized_bed ...`; `fb` and `bed` are aliases).

Where scenes come from:
- the built-in ones, `neuraldem.scenes.<kind>` for the kinds in `BUILT_IN`;
- installed packages that declare an entry point in the group `neuraldem.scenes` (`name = "package"`);
- folders named in `NEURALDEM_SCENES` (os.pathsep-separated): each folder is a scene package, imported
  under its folder name; its `conf/` folder (data, model, experiment configs) joins the Hydra search path
  (`hydra_plugins/neuraldem_searchpath.py`). `docs/adding-a-scene.md` walks through one.

Scene modules import their heavy parts (solvers, torch models) inside functions, so looking a scene up costs
nothing.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import importlib.util
import os
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from neuraldem.errors import ConfigError

if TYPE_CHECKING:
    from omegaconf import DictConfig

    from neuraldem.scenes.parameters import ParameterTable

BUILT_IN = ("hopper", "hopper_refill", "fluidized_bed")
ENV_VAR = "NEURALDEM_SCENES"
ENTRY_POINT_GROUP = "neuraldem.scenes"


@dataclass(frozen=True)
class Scene:
    """What the generic commands need from a scene. Module references are "package.module" strings (imported
    when the command runs), so registering a scene imports nothing heavy.

    A what-if module (`whatif`) has `add_options(parser)`, `default_model()`, `answer(point, args) -> dict`
    and `table(answer) -> str`; a page module has `TITLE`, `prepare(model, dataset, near)` and
    `page(shared)`; a release module has `add_options(parser)` and `build(args) -> Path`; benchmarks,
    reports and importers are modules with `main(argv) -> int`.
    """

    kind: str
    description: str
    experiment: str  # `neuraldem train experiment=...` that trains a model of this scene (said in errors)
    parameters: ParameterTable
    pipeline: Callable[[DictConfig], Any]  # datagen: the solver pipeline (datagen.driver.Pipeline) of a `data` config
    evaluate: Callable[[DictConfig], None]  # `neuraldem evaluate ckpt=...` of a checkpoint of this kind
    evaluate_run: Callable[[DictConfig, Path], dict[str, Any]]  # after training: score ckpt into <run>/evaluation
    module: str = ""  # "package.module:Class" of its LightningModule (what a checkpoint of this kind builds)
    aliases: tuple[str, ...] = ()  # other names a user may type; the first is the explorer page's route
    whatif: str | None = None  # `neuraldem predict <scene>`
    scan: str | None = None  # `neuraldem scan <scene>`: a module with main(argv) -> int
    page: str | None = None  # the explorer page
    release: str | None = None  # `neuraldem release <scene>`: build a shipped model from a checkpoint
    rollout: Callable[[DictConfig], bool] | None = None  # `neuraldem evaluate rollout ckpt=...`; False: diverged
    benchmarks: Mapping[str, tuple[str, str]] = field(default_factory=dict)  # name -> (module[:function], what)
    reports: Mapping[str, tuple[str, str]] = field(default_factory=dict)  # `neuraldem report NAME`
    exports: Mapping[str, tuple[str, str]] = field(default_factory=dict)  # `neuraldem export NAME`
    importer: tuple[str, str, str] | None = None  # `neuraldem import NAME`: (name, module, what)
    import_match_keys: tuple[str, ...] = ()  # scene keys an imported run must share with a model's (1 %)
    import_report_keys: tuple[str, ...] = ()  # solver settings reported when they differ, not refused
    config_dir: Path | None = None  # a plug-in's own Hydra configs (data/, model/, experiment/)
    # "package.module:NAME" of its scene-file keys (a tuple of parameters.SceneKey): the comments of the files
    # `neuraldem scene new` writes and the reference table of docs/your-own-scene.md
    scene_keys: str | None = None
    # Hydra overrides renamed in this scene, read one release with a note: command config -> {old key: new key}
    renamed_keys: Mapping[str, Mapping[str, str]] = field(default_factory=dict)

    @property
    def route(self) -> str:
        """The explorer page's address (`/hopper`, `/bed`)."""
        return self.aliases[0] if self.aliases else self.kind

    @property
    def names(self) -> tuple[str, ...]:
        return (self.kind, *self.aliases)


def _plugin_folders() -> list[Path]:
    return [Path(p).expanduser().resolve() for p in os.environ.get(ENV_VAR, "").split(os.pathsep) if p.strip()]


def _load_folder(folder: Path) -> Any:
    """A scene package from a folder outside the installed package, imported under the folder's name."""
    init = folder / "__init__.py"
    if not init.is_file():
        raise ConfigError(f"{ENV_VAR} names {folder}, which is not a scene package (no __init__.py)",
                          "point it at a folder whose __init__.py defines SCENE (docs/adding-a-scene.md)")
    name = folder.name
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, init, submodule_search_locations=[str(folder)])
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules[name] = module
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def _packages() -> list[tuple[str, Callable[[], Any], Path | None]]:
    """Where each scene package comes from: (source, importer, plug-in folder), built-in first."""
    from importlib.metadata import entry_points

    out: list[tuple[str, Callable[[], Any], Path | None]] = [
        (f"neuraldem.scenes.{k}", functools.partial(importlib.import_module, f"neuraldem.scenes.{k}"), None)
        for k in BUILT_IN]
    out += [(f"entry point {ep.name} = {ep.value}", ep.load, None) for ep in entry_points(group=ENTRY_POINT_GROUP)]
    out += [(str(folder), functools.partial(_load_folder, folder), folder) for folder in _plugin_folders()]
    return out


@functools.cache
def _registry(env: str) -> dict[str, Scene]:
    scenes: dict[str, Scene] = {}
    for source, load, folder in _packages():
        found = getattr(load(), "SCENE", None)
        if not isinstance(found, Scene):
            raise ConfigError(f"scene plug-in {source} defines no SCENE = Scene(...) in its __init__.py",
                              "see docs/adding-a-scene.md")
        if found.kind in scenes:
            raise ConfigError(f"scene kind {found.kind!r} of {source} is registered twice", "rename its kind")
        if folder is not None and found.config_dir is None and (folder / "conf").is_dir():
            found = dataclasses.replace(found, config_dir=folder / "conf")
        scenes[found.kind] = found
    return scenes


def registry() -> dict[str, Scene]:
    """Every registered scene by kind (built-in, installed plug-ins, then `NEURALDEM_SCENES` folders)."""
    return _registry(os.environ.get(ENV_VAR, ""))


def kinds() -> list[str]:
    return list(registry())


def scene(kind: object, key: str = "data.kind") -> Scene:
    """The registered scene of `kind`; an unknown kind is refused naming `key` and the known kinds."""
    scenes = registry()
    if kind not in scenes:
        raise ConfigError(f"config value {key}={kind!r} is invalid: the scenes are {', '.join(map(repr, scenes))}",
                          f"add a scene plug-in with {ENV_VAR}=FOLDER (docs/adding-a-scene.md)")
    return scenes[kind]  # type: ignore[index]


def by_name(name: str, what: str = "scene") -> Scene:
    """The scene a user typed by kind or alias (`fluidized_bed`, `fb`, `bed`)."""
    for s in registry().values():
        if name in s.names:
            return s
    known = ", ".join(" / ".join(s.names) for s in registry().values())
    raise ConfigError(f"unknown {what} {name!r}", f"choose one of: {known}")


def import_class(ref: str) -> Any:
    """`package.module:Name` as the object it names."""
    module, _, name = ref.partition(":")
    return getattr(importlib.import_module(module), name)


def config_dirs() -> list[Path]:
    """The Hydra config folders of plug-in scenes (joined to the search path of every command)."""
    return [s.config_dir for s in registry().values() if s.config_dir is not None]
