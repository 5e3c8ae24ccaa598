"""What a checkpoint is, read before loading it: every neuraldem checkpoint carries its data's metadata
(kind, dataset, scene, conditioning, normalisation), so a tool can refuse a model of another kind or scene
with a message instead of failing somewhere inside the model."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from neuraldem.data.manifest import Manifest, SimRecord, require_dataset
from neuraldem.errors import DataError

TRAIN_HINT = {"hopper": "experiment=hopper_micro", "fluidized_bed": "experiment=fb",
              "gns": "experiment=gns_hopper (or gns_fb)"}


def checkpoint_metadata(path: Path) -> dict[str, Any]:
    """The metadata dict of a checkpoint written by `neuraldem.train` (memory-mapped: weights not read)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"checkpoint {path} does not exist")
    try:
        raw = torch.load(path, map_location="cpu", weights_only=False, mmap=True)
    except Exception as err:  # noqa: BLE001 - any unreadable file
        raise DataError(f"{path} is not a readable checkpoint ({type(err).__name__})") from None
    meta = raw.get("hyper_parameters", {}).get("metadata") if isinstance(raw, dict) else None
    if not meta or "kind" not in meta:
        raise DataError(f"{path} is not a neuraldem checkpoint (no metadata): train one with "
                        "python -m neuraldem.train experiment=...")
    return meta


def require_kind(meta: dict[str, Any], kind: str, path: Path, purpose: str) -> None:
    if meta.get("kind") != kind:
        raise DataError(f"{path} is a {meta.get('kind')!r} checkpoint (trained on {meta.get('data_name')!r}); "
                        f"{purpose} needs a {kind} model: train one with python -m neuraldem.train "
                        f"{TRAIN_HINT.get(kind, 'experiment=...')}")


def check_scene(meta: dict[str, Any], m: Manifest, ckpt: Path, dataset_dir: Path) -> None:
    """The dataset must come from the scene the model was trained on (geometry, material, solver settings)."""
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
