"""`manifest.json` of a dataset dir: scene, solver, parameter table, per-simulation status and splits.

The manifest is the index of a dataset: a simulation counts only when its record says `ok` and its file
exists with the recorded checksum. Failed and clogged runs stay listed (with the reason) but are never in
a split. Written atomically after every finished simulation, so a killed datagen loses nothing finished.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from neuraldem.data.schema import SCHEMA_VERSION, atomic_write_json, check_version
from neuraldem.errors import DataError
from neuraldem.paths import data_dir

MANIFEST_NAME = "manifest.json"
STATUSES = ("pending", "ok", "clogged", "failed")


@dataclass
class SimRecord:
    sim_id: str
    index: int
    params: dict[str, float]
    status: str = "pending"
    reason: str = ""
    file: str | None = None  # relative to the dataset dir
    sha256: str | None = None
    macro: dict[str, float] = field(default_factory=dict)  # theta, repose, ... (characterization)
    metrics: dict[str, float] = field(default_factory=dict)  # ground-truth metrics (eval functions)
    cost: dict[str, float] = field(default_factory=dict)  # cpu_s, wall_s, particle_steps, ...
    diagnostics: dict[str, Any] = field(default_factory=dict)

    @property
    def usable(self) -> bool:
        return self.status == "ok" and self.file is not None

    def conditioning(self) -> dict[str, float]:
        """All scalars a model may be conditioned on: sampled parameters + macroscopic measurements."""
        return {**self.params, **self.macro}


@dataclass
class Manifest:
    name: str
    kind: str
    scene: dict[str, Any]
    solver: dict[str, str]
    parameters: dict[str, Any]  # names, ranges, sampling seed
    simulations: list[SimRecord] = field(default_factory=list)
    splits: dict[str, dict[str, list[str]]] = field(default_factory=dict)
    split_info: dict[str, Any] = field(default_factory=dict)  # how each split was made (e.g. band limits)
    # settings of the macroscopic characterization behind `SimRecord.macro` (hopper); when they change,
    # the measurements are redone without rerunning the simulations
    characterization: dict[str, Any] | None = None
    # settings of the metric functions behind `SimRecord.metrics`; datagen rescores when they change
    metric_settings: dict[str, Any] | None = None
    schema_version: int = SCHEMA_VERSION
    created_utc: str = field(default_factory=lambda: _now())
    updated_utc: str = field(default_factory=lambda: _now())

    # ---- lookup
    def record(self, sim_id: str) -> SimRecord:
        for rec in self.simulations:
            if rec.sim_id == sim_id:
                return rec
        raise DataError(f"simulation {sim_id!r} is not in the manifest of dataset {self.name!r}")

    def usable(self) -> list[SimRecord]:
        return [r for r in self.simulations if r.usable]

    def split_ids(self, split: str, part: str) -> list[str]:
        if split not in self.splits:
            raise DataError(f"dataset {self.name!r} has no split {split!r} (has {sorted(self.splits)}); "
                            "rerun datagen to recompute splits")
        return list(self.splits[split][part])

    # ---- I/O
    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["simulations"] = [asdict(r) for r in self.simulations]
        return out

    def save(self, dataset_dir: Path) -> None:
        self.updated_utc = _now()
        Path(dataset_dir).mkdir(parents=True, exist_ok=True)
        atomic_write_json(Path(dataset_dir) / MANIFEST_NAME, self.to_json())

    @classmethod
    def load(cls, dataset_dir: Path) -> Manifest:
        path = Path(dataset_dir) / MANIFEST_NAME
        try:
            raw = json.loads(path.read_text())
        except FileNotFoundError:
            raise DataError(f"no manifest at {path}") from None
        except json.JSONDecodeError as err:
            raise DataError(f"{path} is not valid JSON ({err})",
                            "restore it, or delete the dataset dir and rerun datagen") from None
        check_version(raw.get("schema_version"), path)
        try:
            sims = [SimRecord(**r) for r in raw.pop("simulations", [])]
            m = cls(**raw, simulations=sims)
        except TypeError as err:
            raise DataError(f"{path}: unexpected manifest layout ({err})") from None
        for r in m.simulations:
            if r.status not in STATUSES:
                raise DataError(f"{path}: simulation {r.sim_id} has unknown status {r.status!r}",
                                f"set it to one of {list(STATUSES)} (pending reruns it with datagen)")
        return m


def find_dataset(text: str) -> Path:
    """A dataset given on a command line: the folder as given when it holds a manifest, else the dataset of that
    name under <data dir>/datasets when that does, else the folder as given (for the caller's error)."""
    path = Path(text).expanduser()
    named = data_dir() / "datasets" / text
    if not (path / MANIFEST_NAME).is_file() and (named / MANIFEST_NAME).is_file():
        return named
    return path


def require_dataset(dataset_dir: Path, data_name: str) -> Manifest:
    """The manifest of an existing dataset, or the one-line error that says how to make it."""
    dataset_dir = Path(dataset_dir)
    if not (dataset_dir / MANIFEST_NAME).is_file():
        raise DataError(f"no dataset at {dataset_dir}: generate it with "
                        f"`neuraldem datagen data={data_name}`")
    m = Manifest.load(dataset_dir)
    if not m.usable():
        raise DataError(f"dataset {dataset_dir} has no finished simulation yet: run "
                        f"`neuraldem datagen data={data_name}` (it resumes where it stopped)")
    return m


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")
