"""Pretrained models shipped inside the package, loaded by name.

Each model is a folder `neuraldem/pretrained/<name>/` with its files and a `meta.json` that says what they are:
the scene kind, the training data (dataset name and the SHA-256 of its manifest, the run ids of each part),
the config it was trained with, its errors measured on its held-out test runs (beside the constant and the
solver's seed floor), answers at a few probe points (what a test reproduces), and the commands that rebuild it
(`neuraldem release`). Every file is checked against the checksum in meta.json before first
use; a missing or damaged one is refused with its path and the rebuild command.

`NEURALDEM_PRETRAINED_DIR` points the loader at another folder of the same layout (your own rebuilt models).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neuraldem.data.integrity import digest
from neuraldem.errors import ConfigError, DataError
from neuraldem.pretrained.card import check_card

META = "meta.json"


def root() -> Path:
    return Path(os.environ.get("NEURALDEM_PRETRAINED_DIR") or Path(__file__).parent)


def names() -> list[str]:
    """The shipped models (folders with a meta.json)."""
    return sorted(p.parent.name for p in root().glob(f"*/{META}"))


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
    """The shipped model `name` (of scene `kind` when given); an unknown name lists the shipped ones."""
    available = names()
    if kind is not None:
        available = [n for n in available if _meta_kind(n) == kind]
    if name not in available:
        what = f"{kind} models" if kind else "models"
        raise ConfigError(f"unknown pretrained model {name!r}",
                          f"the shipped {what} are: {', '.join(available) or 'none'} (in {root()})")
    folder = root() / name
    try:
        meta = json.loads((folder / META).read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise DataError(f"{folder / META} is unreadable ({type(err).__name__})",
                        "reinstall neuraldem or rebuild the model with neuraldem release") from None
    check_card(folder, f"neuraldem release {meta.get('kind', '')} name={name} out={folder.parent} card_only=true")
    return Pretrained(name, folder, meta)


def _meta_kind(name: str) -> str | None:
    try:
        return json.loads((root() / name / META).read_text()).get("kind")
    except (OSError, json.JSONDecodeError):
        return None


def default_for(kind: str) -> str:
    """The shipped model a scene's commands use unless told otherwise."""
    for name in names():
        if _meta_kind(name) == kind:
            return name
    raise ConfigError(f"no pretrained {kind} model is shipped in {root()}",
                      "build one with neuraldem release (see its --help)")
