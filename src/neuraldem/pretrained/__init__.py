"""Released models, loaded by name or folder: the shipped ones inside the package and your own.

Each model is a folder `<name>/` with its files and a `meta.json` that says what they are: the scene kind, the
training data (dataset name and the SHA-256 of its manifest, the run ids of each part), the config it was trained
with, its errors measured on its held-out test runs (beside the constant and the solver's seed floor), the ranges
it was trained on (covered by its runs, and asked of datagen), answers at a few probe points (what a test
reproduces), and the commands that rebuild it (`neuraldem release`). Every file is checked against the checksum
in meta.json before first use; a missing or damaged one is refused with its path and the rebuild command.

Where models are found, in this order (the first folder holding a name wins, and a scene's default model is the
first of its kind found):
- `NEURALDEM_MODELS` (folders separated by os.pathsep), default `<data dir>/models`: where `neuraldem release`
  writes unless told otherwise. `NEURALDEM_PRETRAINED_DIR` is its old name, read for one release with a note;
- the models shipped inside the package (`neuraldem/pretrained/`), always: your folders add to them.
`model=` also takes a released model's folder (`model=~/my-models/my_hopper`, a folder with meta.json).
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neuraldem.data.integrity import digest
from neuraldem.errors import ConfigError, DataError
from neuraldem.paths import data_dir
from neuraldem.pretrained.card import check_card

META = "meta.json"
ENV_VAR = "NEURALDEM_MODELS"
OLD_ENV_VAR = "NEURALDEM_PRETRAINED_DIR"  # its old name (one release)
_noted: list[bool] = []


def shipped_dir() -> Path:
    """The models shipped inside the package."""
    return Path(__file__).parent


def user_dirs() -> list[Path]:
    """Your model folders (`NEURALDEM_MODELS`, else the old `NEURALDEM_PRETRAINED_DIR`, else <data dir>/models)."""
    value = os.environ.get(ENV_VAR)
    if value is None and os.environ.get(OLD_ENV_VAR):
        value = os.environ[OLD_ENV_VAR]
        if not _noted:
            _noted.append(True)
            print(f"neuraldem: note: {OLD_ENV_VAR} is the old name of {ENV_VAR} (kept for one release); its folders "
                  "are searched before the shipped models, which stay available", file=sys.stderr)
    folders = [Path(p).expanduser() for p in (value or "").split(os.pathsep) if p.strip()]
    return folders or [data_dir() / "models"]


def release_dir() -> Path:
    """Where `neuraldem release` writes a model by default: the first of your model folders."""
    return user_dirs()[0]


def search_dirs() -> list[Path]:
    """Every folder models are found in, in order: yours, then the shipped ones."""
    out: list[Path] = []
    for folder in [*user_dirs(), shipped_dir()]:
        if folder.resolve() not in [f.resolve() for f in out]:
            out.append(folder)
    return out


def root() -> Path:
    """The folder of the shipped models (kept for callers of the old API)."""
    return shipped_dir()


def found() -> dict[str, Path]:
    """Every model found: name -> folder, the first folder in search order winning."""
    out: dict[str, Path] = {}
    for folder in search_dirs():
        for meta in sorted(folder.glob(f"*/{META}")):
            out.setdefault(meta.parent.name, meta.parent)
    return out


def names() -> list[str]:
    """The models found (folders with a meta.json), yours first."""
    return list(found())


def is_folder_reference(name: str) -> bool:
    """`model=` names a folder (a path) rather than a model found by name."""
    return os.sep in name or name.startswith(("~", ".")) or (os.altsep is not None and os.altsep in name)


@dataclass(frozen=True)
class Pretrained:
    name: str
    folder: Path
    meta: dict[str, Any]

    @property
    def kind(self) -> str:
        return str(self.meta["kind"])

    @property
    def rebuild(self) -> str:
        return " && ".join(self.meta.get("rebuild", [])) or "neuraldem release --help"

    def file(self, role: str) -> Path:
        """The verified path of one of the model's files ('field', 'gp', ...)."""
        entry = self.meta.get("files", {}).get(role)
        if entry is None:
            raise DataError(f"pretrained model {self.name!r} has no {role!r} file "
                            f"(it has {', '.join(self.meta.get('files', {})) or 'none'})")
        path = self.folder / entry["file"]
        if not path.is_file():
            raise DataError(f"shipped model file {path} is missing", f"rebuild it: {self.rebuild}")
        if digest(path) != entry["sha256"]:
            raise DataError(f"shipped model file {path} is damaged (its SHA-256 differs from {self.folder / META})",
                            f"reinstall neuraldem or rebuild it: {self.rebuild}")
        return path


def load(name: str, kind: str | None = None) -> Pretrained:
    """The model `name` (a name found in the model folders, or a released model's folder), of scene `kind` when
    given; an unknown name lists the models found, a folder that is not a released model says how to make one."""
    if is_folder_reference(name):
        folder = Path(name).expanduser()
        if not (folder / META).is_file():
            inside = sorted(p.parent.name for p in folder.glob(f"*/{META}")) if folder.is_dir() else []
            fix = (f"it holds the models {', '.join(inside)}: pass model={folder / inside[0]}" if inside else
                   f"release a checkpoint into it first: neuraldem release ckpt=RUN/checkpoints/last.ckpt "
                   f"name={folder.name} out={folder.parent}")
            raise ConfigError(f"model={name}: {folder} is not a released model (no {META})", fix)
        model = _read(folder.name, folder)
        if kind is not None and model.kind != kind:
            raise ConfigError(f"model={name} is a {model.kind} model, not a {kind} one",
                              f"pass a {kind} model (neuraldem predict {kind} --help lists them)")
        return model
    models = found()
    available = [n for n in models if kind is None or _meta_kind(models[n]) == kind]
    if name not in available:
        what = f"{kind} models" if kind else "models"
        raise ConfigError(f"unknown pretrained model {name!r}",
                          f"the {what} found are: {', '.join(available) or 'none'} (in "
                          f"{os.pathsep.join(map(str, search_dirs()))}); or pass a released model's folder, "
                          "model=PATH")
    return _read(name, models[name])


def _read(name: str, folder: Path) -> Pretrained:
    try:
        meta = json.loads((folder / META).read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise DataError(f"{folder / META} is unreadable ({type(err).__name__})",
                        "reinstall neuraldem or rebuild the model with neuraldem release") from None
    check_card(folder, f"neuraldem release {meta.get('kind', '')} name={name} out={folder.parent} card_only=true")
    return Pretrained(name, folder, meta)


def _meta_kind(folder: Path) -> str | None:
    try:
        return json.loads((folder / META).read_text()).get("kind")
    except (OSError, json.JSONDecodeError):
        return None


def default_for(kind: str) -> str:
    """The model a scene's commands use unless told otherwise: the first of its kind in search order (yours
    first, then the shipped one)."""
    for name, folder in found().items():
        if _meta_kind(folder) == kind:
            return name
    raise ConfigError(f"no pretrained {kind} model is shipped in {shipped_dir()} nor found in "
                      f"{os.pathsep.join(map(str, user_dirs()))}",
                      "build one with neuraldem release (see its --help)")
