"""One writer per dataset, and files read only as the manifest recorded them."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from neuraldem.data import integrity
from neuraldem.data.integrity import dataset_lock, verify_recorded_checksum
from neuraldem.data.manifest import Manifest
from neuraldem.errors import DataError
from neuraldem.scenes.hopper.dataset.store import HopperFile
from tests.helpers import REPO, flip_byte, run_module

HOLD = ("import sys, time; from neuraldem.data.integrity import dataset_lock\n"
        "with dataset_lock(sys.argv[1], 'neuraldem datagen data=x'):\n"
        "    print('held', flush=True); time.sleep(60)\n")


def hold_lock(dataset: Path) -> subprocess.Popen[str]:
    """Another process holding the dataset's writer lock (returns once it holds it)."""
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(dataset)], stdout=subprocess.PIPE, text=True,
                            cwd=REPO, env=dict(os.environ))
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_writer_is_refused_with_the_pid_of_the_first(tmp_path: Path):
    proc = hold_lock(tmp_path / "ds")
    try:
        with pytest.raises(DataError, match=rf"being written by PID {proc.pid} on .*`neuraldem datagen data=x`"
                                            rf".*kill {proc.pid}"), dataset_lock(tmp_path / "ds", "second"):
            pass
        t0 = time.monotonic()
        with pytest.raises(DataError, match="being written by"), dataset_lock(tmp_path / "ds", "second", wait_s=0.5):
            pass
        assert time.monotonic() - t0 >= 0.4  # it waited before refusing
    finally:
        proc.kill()
        proc.wait()


def test_a_killed_writer_leaves_the_lock_free(tmp_path: Path):
    proc = hold_lock(tmp_path / "ds")
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    with dataset_lock(tmp_path / "ds", "after the kill"):
        assert json.loads((tmp_path / "ds" / integrity.HOLDER_NAME).read_text())["pid"] == os.getpid()
    assert not (tmp_path / "ds" / integrity.HOLDER_NAME).exists()


def test_datagen_on_a_dataset_being_written_is_one_line(tmp_path: Path):
    """`neuraldem datagen` against a dataset another datagen holds: refused at once, nothing written."""
    dataset = tmp_path / "datasets" / "hopper_tiny"
    proc = hold_lock(dataset)
    try:
        before = sorted(p.name for p in dataset.iterdir())
        out = run_module("neuraldem", "datagen", "data=hopper_tiny", "n_sims=1", "progress=false",
                         env={"NEURALDEM_DATA": str(tmp_path)})
        assert out.returncode == 2, out.stderr
        lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and f"PID {proc.pid}" in lines[0] and "Traceback" not in out.stderr
        assert sorted(p.name for p in dataset.iterdir()) == before
    finally:
        proc.kill()
        proc.wait()


@pytest.fixture
def copied_dataset(hopper_tiny_dataset: Path, tmp_path: Path) -> Path:
    out = tmp_path / "hopper_tiny"
    shutil.copytree(hopper_tiny_dataset, out)
    return out


def test_a_changed_file_is_refused_naming_file_manifest_and_fix(copied_dataset: Path):
    rec = Manifest.load(copied_dataset).usable()[0]
    path = copied_dataset / str(rec.file)
    with HopperFile(path):
        pass  # as written: opens
    flip_byte(path)
    with pytest.raises(DataError) as err:
        HopperFile(path)
    msg = str(err.value)
    assert str(path) in msg and "manifest.json" in msg and rec.sim_id in msg
    assert "neuraldem datagen data=hopper_tiny" in msg


def test_the_writer_of_a_dataset_reads_its_own_files_unchecked(copied_dataset: Path):
    path = copied_dataset / str(Manifest.load(copied_dataset).usable()[0].file)
    flip_byte(path)
    with dataset_lock(copied_dataset, "test"):
        verify_recorded_checksum(path)  # datagen rewriting a run reads it back before the manifest is updated
    with pytest.raises(DataError, match="contents differ"):
        verify_recorded_checksum(path)


def test_a_file_is_hashed_once_per_process(copied_dataset: Path, monkeypatch: pytest.MonkeyPatch):
    calls = []
    real = integrity.sha256
    monkeypatch.setattr(integrity, "sha256", lambda p: calls.append(p) or real(p))
    integrity._digest.cache_clear()
    path = copied_dataset / str(Manifest.load(copied_dataset).usable()[0].file)
    for _ in range(3):
        verify_recorded_checksum(path)
    assert len(calls) == 1
    os.utime(path, ns=(time.time_ns(), time.time_ns() + 10**9))  # touched: hashed again
    verify_recorded_checksum(path)
    assert len(calls) == 2


def test_files_outside_a_dataset_or_not_recorded_are_not_checked(copied_dataset: Path, tmp_path: Path):
    loose = tmp_path / "loose.h5"
    shutil.copy(copied_dataset / str(Manifest.load(copied_dataset).usable()[0].file), loose)
    flip_byte(loose)
    verify_recorded_checksum(loose)
    stray = copied_dataset / "sims" / "not_in_manifest.h5"
    shutil.copy(loose, stray)
    verify_recorded_checksum(stray)


def test_training_on_a_damaged_file_ends_in_one_line_naming_it(copied_dataset: Path, tmp_path: Path):
    path = copied_dataset / str(Manifest.load(copied_dataset).usable()[0].file)
    flip_byte(path)
    out = run_module("neuraldem", "train", "experiment=hopper_quickstart", "logger=none",
                     f"data.dataset_dir={copied_dataset}", f"hydra.run.dir={tmp_path}/run",
                     env={"NEURALDEM_DATA": str(tmp_path)})
    assert out.returncode == 2 and "Traceback" not in out.stderr
    errors = [ln for ln in out.stderr.splitlines() if "error" in ln.lower()]
    assert len(errors) == 1 and str(path) in errors[0] and "contents differ" in errors[0], out.stderr[-2000:]
    assert "Error in call to target" not in out.stderr
