"""A dataset has one writer at a time, and its files are read only as the manifest recorded them.

`dataset_lock` is held by everything that writes a dataset (datagen, the importers, transfer): a second
writer is refused with the PID and command of the first instead of running the same simulations in the same
folders. The lock is an OS file lock (`filelock`): a killed writer releases it with its process.

`verify_recorded_checksum` is called by every dataset reader before it opens a file: the file's SHA-256 must
be the one in the dataset's `manifest.json`. A digest is computed once per process and file (cached by path,
size and modification time), so a datamodule that opens the same file again pays only a `stat`. A writer
reading back what it is writing (before the manifest has the new checksum) holds the dataset's lock (or is an
array task of the process that holds it, `writing_for`), and reads of its own dataset are not checked.
"""

from __future__ import annotations

import functools
import json
import os
import socket
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, ClassVar

import h5py
from filelock import FileLock, Timeout

from neuraldem.cli import tool_prog
from neuraldem.data.manifest import MANIFEST_NAME, Manifest
from neuraldem.data.schema import REWRITE_FIX, check_version, sha256
from neuraldem.errors import DataError

LOCK_NAME = ".writer.lock"
HOLDER_NAME = ".writer.json"  # who holds the lock: pid, host, command, since
_WRITING: set[Path] = set()  # datasets this process holds the lock of


def _holder(dataset_dir: Path) -> dict[str, Any]:
    try:
        return json.loads((dataset_dir / HOLDER_NAME).read_text())
    except (OSError, ValueError):
        return {}


@contextmanager
def dataset_lock(dataset_dir: Path, command: str, wait_s: float = 0.0) -> Iterator[None]:
    """Hold the dataset's writer lock (waiting up to `wait_s` seconds for another writer); refuse with
    who holds it when it stays taken."""
    dataset_dir = Path(dataset_dir).resolve()
    dataset_dir.mkdir(parents=True, exist_ok=True)
    lock = FileLock(dataset_dir / LOCK_NAME)
    try:
        lock.acquire(timeout=wait_s)
    except Timeout:
        h = _holder(dataset_dir)
        who = (f"PID {h.get('pid')} on {h.get('host')}, `{h.get('command')}` since {h.get('since')}" if h
               else "another process")
        raise DataError(f"{dataset_dir} is being written by {who}; two writers would run the same simulations "
                        "in the same folders",
                        f"wait for it to finish, or stop it (kill {h.get('pid', 'PID')}) and run this again: "
                        "finished work is kept") from None
    try:
        holder = {"pid": os.getpid(), "host": socket.gethostname(), "command": command,
                  "since": datetime.now(UTC).isoformat(timespec="seconds")}
        (dataset_dir / HOLDER_NAME).write_text(json.dumps(holder))
        _WRITING.add(dataset_dir)
        yield
    finally:
        _WRITING.discard(dataset_dir)
        (dataset_dir / HOLDER_NAME).unlink(missing_ok=True)
        lock.release()


@contextmanager
def writing_for(dataset_dir: Path) -> Iterator[None]:
    """Inside an array task of a datagen (neuraldem.datagen.executors): the task writes part of the dataset for the
    datagen that submitted it (which holds the lock, or left the job in the dataset's array_jobs.json) and reads
    back its own new files before the manifest has their checksums, as the lock holder does."""
    dataset_dir = Path(dataset_dir).resolve()
    _WRITING.add(dataset_dir)
    try:
        yield
    finally:
        _WRITING.discard(dataset_dir)


@functools.lru_cache(maxsize=8192)
def _digest(path: str, size: int, mtime_ns: int) -> str:
    return sha256(Path(path))


@functools.lru_cache(maxsize=64)
def _recorded(dataset_dir: Path, mtime_ns: int) -> tuple[str, bool, dict[str, tuple[str, str]]]:
    """(dataset name, imported?, {relative file: (sim_id, sha256)}) of the usable records of a manifest."""
    try:
        m = Manifest.load(dataset_dir)
    except DataError:
        return "", False, {}  # a broken manifest is refused where the dataset is loaded, with its own message
    files = {str(r.file): (r.sim_id, r.sha256) for r in m.usable() if r.sha256}
    return m.name, bool(m.scene.get("imported")), files


def digest(path: Path) -> str:
    """SHA-256 of a file, computed once per process while its size and modification time stay the same."""
    st = Path(path).stat()
    return _digest(str(Path(path).resolve()), st.st_size, st.st_mtime_ns)


def verify_recorded_checksum(path: Path) -> None:
    """Refuse a dataset file whose contents differ from the checksum its manifest recorded (changed or damaged
    after it was written). Files outside a dataset, or not (yet) recorded, are not checked."""
    path = Path(path).resolve()
    for dataset_dir in (path.parent, path.parent.parent):
        manifest = dataset_dir / MANIFEST_NAME
        if not manifest.is_file():
            continue
        if dataset_dir in _WRITING:
            return
        name, imported, files = _recorded(dataset_dir, manifest.stat().st_mtime_ns)
        entry = files.get(path.relative_to(dataset_dir).as_posix())
        if entry is None or digest(path) == entry[1]:
            return
        sim_id = entry[0]
        fix = (f"import {sim_id} again (neuraldem import ...)" if imported else
               f"delete it and run `neuraldem datagen data={name}` to regenerate it (finished runs are kept)")
        raise DataError(f"{path}: its contents differ from the SHA-256 that {manifest} recorded for {sim_id} "
                        "(the file was changed or damaged after it was written)", fix)


def command_line(module: str) -> str:
    """The command as typed (`neuraldem datagen ...` or `python -m <module> ...`), for the lock's holder record."""
    return " ".join([tool_prog(module), *sys.argv[1:]])


class ValidatedH5File:
    """Base of the dataset readers: opens the file, refuses other schema versions and kinds, and names the
    file and the field in every error. Subclasses set KIND and implement `_read_meta` and `validate`."""

    KIND: ClassVar[str]

    def __init__(self, path: Path, validate: bool = True):
        self.path = Path(path)
        if not self.path.is_file():
            raise DataError(f"dataset file {self.path} does not exist (regenerate with neuraldem datagen)")
        verify_recorded_checksum(self.path)
        try:
            self.f = h5py.File(self.path, "r")
        except OSError as err:
            raise DataError(f"{self.path}: not a readable HDF5 file ({err})", REWRITE_FIX) from None
        try:
            check_version(self.f.attrs.get("schema_version"), self.path)
            if self.f.attrs.get("kind") != self.KIND:
                raise DataError(f"{self.path}: kind {self.f.attrs.get('kind')!r}, expected {self.KIND!r}")
            self._read_meta()
            if validate:
                self.validate()
        except DataError as err:
            self.f.close()
            if err.fix:
                raise
            raise DataError(err.problem, REWRITE_FIX) from None
        except Exception:
            self.f.close()
            raise

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.f.close()

    def _field(self, name: str) -> Any:
        if name not in self.f:
            raise DataError(f"{self.path}: field /{name} is missing (file from another tool or truncated)")
        return self.f[name]

    def _read_meta(self) -> None:
        raise NotImplementedError

    def validate(self) -> None:
        raise NotImplementedError
