"""Where Hydra commands find configs, yours included, and the checks made before Hydra composes.

Every Hydra command (`datagen`, `train`, `evaluate`) searches, in this order: the packaged configs (`conf/`), the
`conf/` folders of scene plug-ins (`NEURALDEM_SCENES`), then your user config folder (`$NEURALDEM_CONFIG`, default
`~/.config/neuraldem`; `neuraldem scene new` writes its scene files into `data/` there). A name is found in one
place only: a file of yours named like a packaged config would be shadowed by it, so it is refused (one line,
both files) instead of being silently ignored. A group option found nowhere (`data=nope`) is refused before
Hydra composes, naming the folders searched and how to add one.
"""

from __future__ import annotations

import re
from pathlib import Path

from neuraldem.errors import ConfigError
from neuraldem.paths import config_dir, user_config_dir

SCENE_GROUP = "data"  # the config group whose options are scenes (`data=hopper_small`)
SIMPLE_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")


def search_folders() -> list[tuple[str, Path]]:
    """(what, folder) of every config root a Hydra command searches, in its order."""
    from neuraldem.scenes import registry

    out = [("packaged", config_dir())]
    out += [(f"scene plug-in {s.kind}", s.config_dir) for s in registry().values() if s.config_dir is not None]
    out.append(("yours", user_config_dir()))
    return out


def config_files(group: str, name: str) -> list[tuple[str, Path]]:
    """(what, file) of every `<group>/<name>.yaml` in the search folders."""
    return [(what, folder / group / f"{name}.yaml") for what, folder in search_folders()
            if (folder / group / f"{name}.yaml").is_file()]


def group_options(group: str) -> dict[str, tuple[str, Path]]:
    """Every option of a config group: name -> (where, file), the first found in search order."""
    out: dict[str, tuple[str, Path]] = {}
    for what, folder in search_folders():
        for path in sorted((folder / group).glob("*.yaml")) if (folder / group).is_dir() else []:
            out.setdefault(path.stem, (what, path))
    return out


def config_file(group: str, name: str) -> Path:
    """The one file of `<group>/<name>`; refused when it is found nowhere or in two places."""
    found = config_files(group, name)
    if len(found) > 1:
        (a, pa), (b, pb) = found[:2]
        raise ConfigError(f"{group}={name} is found twice: {pa} ({a}) and {pb} ({b}); the first would silently "
                          f"win", f"rename or remove {pb}")
    if not found:
        folders = ", ".join(str(folder / group) for _, folder in search_folders())
        how = (f"write one with `neuraldem scene new {name} from=hopper_small` (or from=fb_small; `neuraldem scene "
               f"list` shows the scenes)" if group == SCENE_GROUP
               else f"choose one of {', '.join(sorted(group_options(group))) or 'none'}")
        raise ConfigError(f"no {group} config {name!r}: searched {folders}", how)
    return found[0][1]


def check_group_choice(group: str, value: str) -> None:
    """A `group=value` override (a comma list in a sweep) names options that exist, each in one place."""
    if value in ("null", "None", "") or not (config_dir() / group).is_dir():
        return
    for name in value.split(","):
        name = name.strip()
        if SIMPLE_NAME.fullmatch(name):  # sweeps like choice(...), globs and interpolations are Hydra's to read
            config_file(group, name)


def with_scene_file(err: ConfigError, choices: dict[str, str]) -> ConfigError:
    """A config error about a `data.` key, naming the file the chosen scene came from so a user edits the
    right file (`scene file ~/.config/neuraldem/data/my_hopper.yaml: unknown key(s) ['x'] in data.scene ...`)."""
    if not re.search(rf"\b{SCENE_GROUP}\.", err.problem) or not choices.get(SCENE_GROUP):
        return err
    try:
        path = config_file(SCENE_GROUP, str(choices[SCENE_GROUP]))
    except ConfigError:
        return err
    fix = err.fix or (f"correct it in that file (docs/your-own-scene.md lists every key; `neuraldem scene show "
                      f"{choices[SCENE_GROUP]}` prints the scene it composes)")
    return ConfigError(f"scene file {path}: {err.problem}", fix)


def scene_config(text: str) -> tuple[Path, dict]:
    """A scene's `data` config as a plain dict, from a scene name (`my_hopper`, `hopper_small`) or a YAML file: its
    `defaults:` chain merged the way Hydra merges it (bases first), interpolations left as they are. What an
    importer reads from a scene (`scene:`, `metrics:`, `storage:`) holds none."""
    from omegaconf import OmegaConf

    path = Path(text).expanduser()
    if not path.is_file():
        if path.suffix in (".yaml", ".yml") or "/" in text:
            raise ConfigError(f"scene={text}: no such file", "give a scene file, a scene name (neuraldem scene "
                              "list) or a dataset folder")
        path = config_file(SCENE_GROUP, text)

    def merged(file: Path, seen: tuple[Path, ...]) -> dict:
        own = OmegaConf.to_container(OmegaConf.load(file), resolve=False) or {}
        if not isinstance(own, dict):
            raise ConfigError(f"scene={text}: {file} is not a scene file (no mapping)")
        bases = [d for d in own.pop("defaults", []) or [] if isinstance(d, str) and d != "_self_"]
        out = OmegaConf.create()
        for base in bases:
            base_file = config_file(SCENE_GROUP, base)
            if base_file not in seen:
                out = OmegaConf.merge(out, merged(base_file, (*seen, base_file)))
        return OmegaConf.to_container(OmegaConf.merge(out, own), resolve=False)  # type: ignore[return-value]

    return path, merged(path, (path,))
