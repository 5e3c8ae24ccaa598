"""Schema versions and shared I/O rules of dataset files (documented in docs/data-format.md).

Bump SCHEMA_VERSION whenever a reader could misread an older file; readers refuse other versions.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py

from neuraldem.errors import DataError

SCHEMA_VERSION = 1
TMP_SUFFIX = ".partial"
# what to do about a dataset file a reader refuses
REWRITE_FIX = ("delete the file and rerun the datagen command of its dataset (finished runs are kept), or import "
               "it again")


def check_version(found: Any, path: Path) -> None:
    if hasattr(found, "item"):  # numpy scalar from an HDF5 attribute
        found = found.item()
    if found != SCHEMA_VERSION:
        raise DataError(f"{path}: schema version {found!r}, this neuraldem reads version {SCHEMA_VERSION}",
                        "regenerate the dataset with `neuraldem datagen` (finished runs are reused) or "
                        "install the neuraldem version that wrote it")


def atomic_write_h5(path: Path, fill: Callable[[h5py.File], None]) -> None:
    """Write an HDF5 file under a temporary name, flush it to disk, then rename: a reader never sees a
    half-written file under the final name, and a kill mid-write leaves only the temporary file."""
    path = Path(path)
    tmp = path.with_name(path.name + TMP_SUFFIX)
    try:
        with h5py.File(tmp, "w") as f:
            fill(f)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def atomic_write_json(path: Path, obj: Any) -> None:
    path = Path(path)
    tmp = path.with_name(path.name + TMP_SUFFIX)
    with open(tmp, "w") as fh:
        json.dump(obj, fh, indent=1, sort_keys=False, default=_json_default)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _json_default(obj: Any) -> Any:
    import numpy as np

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def sha256(path: Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()
