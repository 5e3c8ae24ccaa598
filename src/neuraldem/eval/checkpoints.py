"""What a checkpoint is, read before loading it: every neuraldem checkpoint carries its data's metadata
(kind, dataset, scene, conditioning, normalisation), so a tool can refuse a model of another kind or scene
with a message instead of failing somewhere inside the model."""

from __future__ import annotations

import copy
import functools
import inspect
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from neuraldem.data.manifest import Manifest, SimRecord, require_dataset
from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes import import_class, registry
from neuraldem.scenes import scene as scene_of

# Imported runs (neuraldem import ...) record the keys of their scene a user can state (`Scene.import_match_keys`):
# geometry and particle size must match the checkpoint's scene within IMPORT_SCENE_RTOL; solver settings such as
# the timestep (`Scene.import_report_keys`) are reported when they differ, not refused.
IMPORT_SCENE_RTOL = 0.01

IMPORTED_SPLIT = "imported (every run)"  # what an evaluation on imported runs reports as its split

# models that are not a scene's own surrogate: the particle-based GNS baseline trains on any scene's store
OTHER_MODELS = {"gns": ("neuraldem.gns.module:GnsModule", "experiment=gns_hopper (or gns_fb)")}


def module_class(kind: str) -> Any:
    """The LightningModule class of a checkpoint kind (imported when a model is built, not when metadata is read)."""
    if kind in OTHER_MODELS:
        return import_class(OTHER_MODELS[kind][0])
    return import_class(scene_of(kind, key="checkpoint kind").module)


def train_hint(kind: str) -> str:
    if kind in OTHER_MODELS:
        return OTHER_MODELS[kind][1]
    return scene_of(kind, key="checkpoint kind").experiment if kind in registry() else "experiment=..."


@dataclass(frozen=True)
class Checkpoint:
    """A checkpoint written by `neuraldem train`, read once (memory-mapped: weights are paged in when used)."""

    path: Path
    raw: dict[str, Any]

    @property
    def hyper_parameters(self) -> dict[str, Any]:
        """A copy (the read is shared by everyone in the process: nobody may change it for the others)."""
        return copy.deepcopy(self.raw.get("hyper_parameters", {}))

    @property
    def metadata(self) -> dict[str, Any]:
        return copy.deepcopy(self.raw["hyper_parameters"]["metadata"])

    @property
    def net_parameters(self) -> int:
        return int(sum(v.numel() for k, v in self.raw.get("state_dict", {}).items() if k.startswith("net.")))

    def module(self, kind: str, device: str = "cpu", purpose: str = "this command") -> Any:
        """The trained LightningModule in eval mode on `device`, built from what was read (as Lightning's
        `load_from_checkpoint` does: constructor arguments from the hyper-parameters, `on_load_checkpoint`, a
        strict state dict); a checkpoint of another kind is refused with the command that trains one."""
        require_kind(self.metadata, kind, self.path, purpose)
        cls = module_class(kind)
        accepted = inspect.signature(cls.__init__).parameters
        module = cls(**{k: v for k, v in self.hyper_parameters.items() if k in accepted})
        checkpoint = {**self.raw, "state_dict": dict(self.raw["state_dict"])}  # hooks may add entries
        module.on_load_checkpoint(checkpoint)
        module.load_state_dict(checkpoint["state_dict"], strict=True)
        return module.to(device).eval()


def checkpoint_net(checkpoint: Checkpoint, kind: str, device: str = "cpu", purpose: str = "this command") -> Any:
    """The trained net alone, built from the checkpoint's `net` config and its `net.*` weights, in eval mode:
    what an answer needs, without the LightningModule (whose Lightning import costs ~1.2 s on a 2-core CPU)."""
    from neuraldem.models.schemas import build_net

    require_kind(checkpoint.metadata, kind, checkpoint.path, purpose)
    net = build_net(checkpoint.hyper_parameters["net"])
    state = {k.removeprefix("net."): v for k, v in checkpoint.raw["state_dict"].items() if k.startswith("net.")}
    net.load_state_dict(state, strict=True)
    return net.to(device).eval()


def resolve_device(device: str) -> str:
    """'auto' = the GPU when there is one."""
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return device


@functools.lru_cache(maxsize=4)
def _read(path: Path, mtime_ns: int, size: int) -> Checkpoint:
    try:
        raw = torch.load(path, map_location="cpu", weights_only=False, mmap=True)
    except Exception as err:  # noqa: BLE001 - any unreadable file
        raise DataError(f"{path} is not a readable checkpoint ({type(err).__name__})") from None
    meta = raw.get("hyper_parameters", {}).get("metadata") if isinstance(raw, dict) else None
    if not meta or "kind" not in meta:
        raise DataError(f"{path} is not a neuraldem checkpoint (no metadata): train one with "
                        "neuraldem train experiment=...")
    return Checkpoint(path, raw)


def read_checkpoint(path: Path) -> Checkpoint:
    """The one way a checkpoint is read: validated, and read once per process (the same file, unchanged on
    disk, is not read again when a command first looks at its metadata and then builds its model)."""
    if not Path(path).is_file():
        raise DataError(f"checkpoint {path} does not exist")
    path = Path(path).resolve()
    stat = path.stat()
    return _read(path, stat.st_mtime_ns, stat.st_size)


def checkpoint_metadata(path: Path) -> dict[str, Any]:
    """The metadata dict of a checkpoint written by `neuraldem train` (kind, dataset, scene, normalisation)."""
    return read_checkpoint(path).metadata


def require_kind(meta: dict[str, Any], kind: str, path: Path, purpose: str) -> None:
    if meta.get("kind") != kind:
        raise DataError(f"{path} is a {meta.get('kind')!r} checkpoint (trained on {meta.get('data_name')!r}); "
                        f"{purpose} needs a {kind} model: train one with neuraldem train "
                        f"{train_hint(kind)}")


def dotted(d: dict[str, Any], key: str) -> Any:
    for part in key.split("."):
        d = d.get(part) if isinstance(d, dict) else None
    return d


def imported_scene_differences(kind: str, trained: dict[str, Any], imported: dict[str, Any],
                               keys: tuple[str, ...] | None = None,
                               rtol: float = IMPORT_SCENE_RTOL) -> list[str]:
    """`key: trained X, imported Y` for every matched key whose values differ by more than rtol (or is missing)."""
    out = []
    for key in scene_of(kind).import_match_keys if keys is None else keys:
        a, b = dotted(trained, key), dotted(imported, key)
        if isinstance(a, list) or isinstance(b, list):  # grid cells: equal or not
            differs = list(a or []) != list(b or [])
        else:
            differs = a is None or b is None or abs(float(a) - float(b)) > rtol * abs(float(a))
        if differs:
            out.append(f"{key}: trained {a}, imported {b}")
    return out


def scene_recorded(kind: str, recorded: dict[str, Any]) -> bool:
    """Whether an imported dataset's manifest states its scene (imports from before scenes were recorded do not)."""
    return any(dotted(recorded, k) is not None for k in scene_of(kind).import_match_keys)


def check_import_joins(m: Manifest, scene: dict[str, Any], dataset: Path, label: str) -> None:
    """One imported dataset holds one scene: a run whose stated scene differs from the dataset's (geometry,
    particles, ... beyond IMPORT_SCENE_RTOL) goes into a dataset of its own; a dataset imported before scenes
    were recorded takes it (and records its scene)."""
    if not m.scene.get("imported"):
        raise ConfigError(f"{dataset} holds generated {m.kind} runs; import your runs into a dataset of their own",
                          fix="pass another dataset= folder")
    if not scene_recorded(m.kind, m.scene):
        return
    diff = imported_scene_differences(m.kind, m.scene, scene)
    if diff:
        raise ConfigError(f"{dataset} holds imported runs of another {label}: {'; '.join(diff)}",
                          fix="import this run into a dataset of its own (dataset=)")


def check_scene(meta: dict[str, Any], m: Manifest, ckpt: Path, dataset_dir: Path) -> None:
    """The dataset must come from the scene the model was trained on (geometry, material, solver settings);
    imported runs must match its geometry and particle size within IMPORT_SCENE_RTOL."""
    if m.scene.get("imported"):
        kind = meta.get("kind", m.kind)
        importable = [s.kind for s in registry().values() if s.import_match_keys]
        if kind not in importable:
            raise DataError(f"{dataset_dir} holds imported {m.kind} runs; scoring a {kind} checkpoint on imported "
                            f"runs is supported for {' and '.join(importable)} models")
        if not scene_recorded(kind, m.scene):
            raise DataError(f"{dataset_dir} was imported without its scene (an import from before scenes were "
                            "recorded)", fix="import the runs again with `neuraldem import liggghts` (or `foam`)")
        diff = imported_scene_differences(kind, meta["scene"], m.scene)
        if diff:
            raise DataError(f"checkpoint {ckpt} was trained on another scene than the runs imported into "
                            f"{dataset_dir} (tolerance {100 * IMPORT_SCENE_RTOL:g} %): {'; '.join(diff)}",
                            fix="score it on runs of the scene it was trained on, or train on yours")
        for note in imported_scene_differences(kind, meta["scene"], m.scene, scene_of(kind).import_report_keys):
            print(f"note: {dataset_dir}: {note} (a solver setting: scored anyway)", file=sys.stderr)
        return
    if meta["scene"] != m.scene:
        keys = differing_keys(meta["scene"], m.scene)
        raise DataError(f"checkpoint {ckpt} was trained on dataset {meta['data_name']!r} whose scene differs "
                        f"from {dataset_dir} (in {keys[:8]}): use data of its own scene")


def checkpoint_dataset(meta: dict[str, Any], ckpt: Path, datasets_dir: Path,
                       dataset_dir: Path | None = None) -> tuple[Path, Manifest]:
    """The dataset a checkpoint is scored on (`dataset_dir`, else the one it was trained on under
    `datasets_dir`) and its manifest; refused when missing or of another scene."""
    dataset_dir = Path(dataset_dir) if dataset_dir else Path(datasets_dir) / meta["data_name"]
    m = require_dataset(dataset_dir, meta["data_name"])
    check_scene(meta, m, Path(ckpt), dataset_dir)
    return dataset_dir, m


def split_records(m: Manifest, dataset_dir: Path, split: str, part: str,
                  max_sims: int | None = None) -> list[SimRecord]:
    """The simulations of one part of a split (the first `max_sims`); refused when there are none."""
    records = [m.record(i) for i in m.split_ids(split, part)][:max_sims]
    if not records:
        raise DataError(f"no {part} simulations in split {split!r} of {dataset_dir}")
    return records


def differing_keys(a: dict[str, Any], b: dict[str, Any], prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two nested dicts."""
    out = []
    for k in sorted(set(a) | set(b)):
        va, vb = a.get(k), b.get(k)
        if isinstance(va, dict) and isinstance(vb, dict):
            out += differing_keys(va, vb, f"{prefix}{k}.")
        elif va != vb:
            out.append(f"{prefix}{k}")
    return out
