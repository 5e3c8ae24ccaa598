"""`neuraldem datagen` on the tiny hopper with the real solver: resume after a kill, failures
recorded and excluded, bad input refused in one line. (Characterization is switched off here to keep the
tests fast; tests/datagen/test_characterized.py covers it.)"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from neuraldem.data.manifest import Manifest
from neuraldem.scenes.hopper.dataset.store import HopperFile
from tests.helpers import REPO, run_module

pytestmark = pytest.mark.solver
FAST = ["data=hopper_tiny", "data.characterization.enabled=false", "progress=false"]


def datagen(root: Path, *args: str, env: dict[str, str] | None = None):
    return run_module("neuraldem", "datagen", *FAST, *args, env={"NEURALDEM_DATA": str(root), **(env or {})})


def manifest(root: Path) -> Manifest:
    return Manifest.load(root / "datasets" / "hopper_tiny")


def test_kill_and_resume_keeps_finished_work(tmp_path: Path):
    env = dict(os.environ, NEURALDEM_DATA=str(tmp_path))
    proc = subprocess.Popen([sys.executable, "-m", "neuraldem", "datagen", *FAST, "n_sims=3"], cwd=REPO, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    path = tmp_path / "datasets" / "hopper_tiny" / "manifest.json"
    deadline = time.time() + 300
    while time.time() < deadline:
        if path.exists() and any(r["status"] == "ok" for r in json.loads(path.read_text())["simulations"]):
            break
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)  # the solver of the next simulation dies with it
    proc.wait()
    first = [r for r in manifest(tmp_path).simulations if r.status == "ok"]
    assert 1 <= len(first) < 3
    done = {r.sim_id: (r.sha256, (tmp_path / "datasets/hopper_tiny" / r.file).stat().st_mtime_ns) for r in first}

    again = datagen(tmp_path, "n_sims=3")
    assert again.returncode == 0, again.stderr
    assert f"{len(first)} finished, {3 - len(first)} to run" in again.stdout + again.stderr
    m = manifest(tmp_path)
    assert [r.status for r in m.simulations] == ["ok"] * 3
    for r in m.simulations:
        if r.sim_id in done:  # untouched: same checksum, same file
            assert (r.sha256, (tmp_path / "datasets/hopper_tiny" / r.file).stat().st_mtime_ns) == done[r.sim_id]
        HopperFile(tmp_path / "datasets/hopper_tiny" / r.file).close()  # readable and valid
    assert not list((tmp_path / "datasets/hopper_tiny").rglob("*.partial"))
    assert "3 ok" in again.stdout and "drainage_time" in again.stdout


def test_failed_run_is_recorded_and_excluded(tmp_path: Path):
    # a stand-in "solver" (test double) that fails for sim_0001 and runs the real LIGGGHTS otherwise
    fake = tmp_path / "liggghts-flaky"
    fake.write_text('#!/bin/sh\ncase "$PWD" in *sim_0001*) echo "ERROR: injected failure"; exit 3;; esac\n'
                    'exec liggghts "$@"\n')
    fake.chmod(0o755)
    proc = datagen(tmp_path, "n_sims=3", env={"NEURALDEM_LIGGGHTS": str(fake)})
    assert proc.returncode == 0, proc.stderr
    m = manifest(tmp_path)
    status = {r.sim_id: r.status for r in m.simulations}
    assert status == {"sim_0000": "ok", "sim_0001": "failed", "sim_0002": "ok"}
    assert "injected failure: exit status 3" in m.record("sim_0001").reason
    for split in m.splits.values():
        assert "sim_0001" not in sum(split.values(), [])
    # not retried by default; retried on request (with the real solver now)
    rerun = datagen(tmp_path, "n_sims=3")
    assert "0 to run" in rerun.stdout + rerun.stderr
    assert datagen(tmp_path, "n_sims=3", "retry_failed=true").returncode == 0
    assert manifest(tmp_path).record("sim_0001").status == "ok"


def test_solver_killed_from_outside_leaves_the_simulation_pending(tmp_path: Path):
    # a stand-in "solver" (test double) that is killed by SIGTERM for sim_0001, the real LIGGGHTS otherwise
    fake = tmp_path / "liggghts-killed"
    fake.write_text('#!/bin/sh\ncase "$PWD" in *sim_0001*) kill -TERM $$;; esac\nexec liggghts "$@"\n')
    fake.chmod(0o755)
    proc = datagen(tmp_path, "n_sims=3", "workers=1", env={"NEURALDEM_LIGGGHTS": str(fake)})
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2 and "Traceback" not in out, out
    assert "stopped by SIGTERM from outside" in out and "run the same command again" in out
    status = {r.sim_id: r.status for r in manifest(tmp_path).simulations}
    # the interrupted one is unfinished, not failed; one the worker had already taken up may finish
    assert status["sim_0000"] == "ok" and status["sim_0001"] == "pending" and status["sim_0002"] in ("pending", "ok")
    rerun = datagen(tmp_path, "n_sims=3", "workers=1")
    assert rerun.returncode == 0 and "to run" in rerun.stdout + rerun.stderr
    assert {r.status for r in manifest(tmp_path).simulations} == {"ok"}


def test_extension_keeps_existing_and_changed_scene_is_refused(tmp_path: Path):
    assert datagen(tmp_path, "n_sims=1").returncode == 0
    params0 = manifest(tmp_path).simulations[0].params
    assert datagen(tmp_path, "n_sims=2").returncode == 0
    m = manifest(tmp_path)
    assert m.simulations[0].params == params0 and len(m.simulations) == 2
    proc = datagen(tmp_path, "n_sims=2", "data.scene.n_particles=400")
    assert proc.returncode == 2
    assert "different scene" in proc.stderr and "hopper.n_particles" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_corrupted_file_is_regenerated(tmp_path: Path):
    assert datagen(tmp_path, "n_sims=1").returncode == 0
    rec = manifest(tmp_path).simulations[0]
    f = tmp_path / "datasets/hopper_tiny" / rec.file
    f.write_bytes(f.read_bytes()[:100])  # e.g. a disk that filled up after the run
    (f.parent / "sim_0009.h5.partial").write_bytes(b"half")  # a write killed mid-way
    proc = datagen(tmp_path, "n_sims=1")
    assert "0 finished, 1 to run" in proc.stdout + proc.stderr
    HopperFile(f).close()
    assert not (f.parent / "sim_0009.h5.partial").exists()


@pytest.mark.parametrize("override,message", [
    ("data.parameters.ranges.alpha=[0,90]", "data.parameters.ranges.alpha[1]=90"),
    ("data.parameters.ranges.mu_s=[0.5,0.1]", "lo <= hi"),
    ("workers=0", "workers=0 is invalid"),
    ("first=[sim_0007]", "first=['sim_0007'] names"),
    ("data.scene.snapshot_interval=0.00015", "multiple of"),
])
def test_bad_values_end_in_one_line(tmp_path: Path, override: str, message: str):
    proc = datagen(tmp_path, "n_sims=1", override)
    assert proc.returncode == 2
    assert message in proc.stderr and "Traceback" not in proc.stderr


def test_first_moves_named_simulations_to_the_front_and_keeps_the_rest_in_order():
    from neuraldem.data.manifest import SimRecord
    from neuraldem.datagen.driver import put_first

    table = [SimRecord(sim_id=f"sim_{i:04d}", index=i, params={}) for i in range(5)]
    todo = [table[i] for i in (4, 0, 2, 3)]
    assert [r.sim_id for r in put_first(todo, ("sim_0003", "sim_0002"), table)] == \
        ["sim_0003", "sim_0002", "sim_0004", "sim_0000"]
    assert put_first(todo, (), table) == todo


def test_killed_at_random_points_equals_an_uninterrupted_run(tmp_path: Path):
    """SIGKILL at seeded random moments (inside a solver run, while writing, between runs), restart each time:
    the finished dataset holds the same runs, positions and metrics as one uninterrupted datagen, and no
    half-written file."""
    import numpy as np

    started = time.monotonic()
    ref = datagen(tmp_path / "ref", "n_sims=3")
    ref_seconds = time.monotonic() - started
    assert ref.returncode == 0, ref.stderr
    root = tmp_path / "killed"
    env = dict(os.environ, NEURALDEM_DATA=str(root))
    rng = np.random.default_rng(22)
    kills = 0
    for _ in range(8):
        proc = subprocess.Popen([sys.executable, "-m", "neuraldem", "datagen", *FAST, "n_sims=3"], cwd=REPO, env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            # kill moments as shares of the uninterrupted run (fixed seconds let a fast machine finish before
            # the second kill): each restart keeps the finished runs, so the first two draws land mid-way
            proc.wait(timeout=max(1.0, float(rng.uniform(0.15, 0.45)) * ref_seconds))
            break  # finished before the kill
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # datagen and its LIGGGHTS
            proc.wait()
            kills += 1
    final = datagen(root, "n_sims=3")  # whatever is left, uninterrupted
    assert final.returncode == 0, final.stderr
    assert kills >= 2  # the draws above stop at least two datagen processes mid-way
    a, b = manifest(tmp_path / "ref"), manifest(root)
    assert [r.status for r in b.simulations] == ["ok"] * 3
    for ra, rb in zip(a.simulations, b.simulations, strict=True):
        assert (ra.sim_id, ra.params, ra.metrics) == (rb.sim_id, rb.params, rb.metrics)
        with HopperFile(tmp_path / "ref/datasets/hopper_tiny" / ra.file) as fa, \
                HopperFile(root / "datasets/hopper_tiny" / rb.file) as fb:
            np.testing.assert_array_equal(fa.positions(), fb.positions())
    assert not list((root / "datasets/hopper_tiny").rglob("*.partial"))
