"""`neuraldem datagen data=fb_tiny` with the real DPMFoam: resume after a kill (mid-trajectory),
a crashed case recorded and excluded while the job goes on, OpenFOAM missing, bad values in one line, the
parameter table and the by-velocity split."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from omegaconf import open_dict

from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.errors import ConfigError
from neuraldem.scenes.fluidized_bed.dataset.datagen import BedPipeline
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from tests.helpers import REPO, compose_cfg, run_module

FAST = ["data=fb_tiny", "progress=false"]


def datagen(root: Path, *args: str, env: dict[str, str] | None = None):
    return run_module("neuraldem", "datagen", *FAST, *args, env={"NEURALDEM_DATA": str(root), **(env or {})})


def manifest(root: Path) -> Manifest:
    return Manifest.load(root / "datasets" / "fb_tiny")


def pipeline(tmp_path: Path, *overrides: str) -> BedPipeline:
    cfg = compose_cfg("datagen", ["data=fb_small", *overrides], output_dir=tmp_path)
    with open_dict(cfg):
        cfg.data.dataset_dir = str(tmp_path / "ds")
    return BedPipeline(cfg.data)


def test_parameter_table_is_deterministic_and_extends(tmp_path: Path):
    pipe = pipeline(tmp_path)
    table = pipe.parameter_sequence(93)
    regular, long = table[:90], table[90:]
    velocities = sorted({p["inlet_velocity"] for p in regular})
    assert len(velocities) == 30 and 1.2 <= velocities[0] < velocities[-1] <= 2.2
    assert [p["packing"] for p in regular[:3]] == [0.0, 1.0, 2.0]
    assert {p["duration"] for p in regular} == {3.0}
    assert [(p["inlet_velocity"], p["duration"]) for p in long] == [(1.35, 30.0), (1.75, 30.0), (2.05, 30.0)]
    # a dataset started with 10 simulations and extended later gets the same table
    m = Manifest(name="fb_small", kind="fluidized_bed", scene={}, solver={}, parameters={})
    pipe.prepare(m)
    first = pipe.new_parameters(10, 0)
    m.simulations = [SimRecord(sim_id=f"s{i}", index=i, params=p) for i, p in enumerate(first)]
    pipe.prepare(m)
    assert first + pipe.new_parameters(83, 1) == table
    more = pipe.parameter_sequence(96)[93:]
    assert all(p["duration"] == 3.0 and p["inlet_velocity"] not in velocities for p in more)
    assert pipe.packing_seed(SimRecord("a", 0, {})) != pipe.packing_seed(SimRecord("b", 1, {}))


def test_run_order_runs_held_out_velocities_first_then_spreads_over_the_range(tmp_path: Path):
    pipe = pipeline(tmp_path)
    table = pipe.parameter_sequence(93)
    m = Manifest(name="x", kind="fluidized_bed", scene={}, solver={}, parameters={})
    m.simulations = [SimRecord(sim_id=f"s{i}", index=i, params=p) for i, p in enumerate(table)]
    order = pipe.run_order(list(reversed(m.simulations)), m)
    assert sorted(r.index for r in order) == list(range(93))  # a permutation: nothing lost or repeated
    first = [r.params for r in order[:30]]
    assert {p["packing"] for p in first} == {0.0}  # every velocity once before any second packing
    assert len({p["inlet_velocity"] for p in first}) == 30
    test_velocities = {float(v) for v in pipe.velocity_parts(m)["test"]}
    n_test = len(test_velocities)
    assert n_test >= 2 and {p["inlet_velocity"] for p in first[:n_test]} == test_velocities  # evaluable early
    rest = order[n_test:30]
    velocities = sorted({p["inlet_velocity"] for p in table[:90]} - test_velocities)
    lo, hi = velocities[0], velocities[-1]
    assert [rest[0].params["inlet_velocity"], rest[1].params["inlet_velocity"]] == [lo, hi]
    for k in (3, 5, 9):  # any prefix leaves no gap wider than about twice the even spacing
        got = sorted(r.params["inlet_velocity"] for r in rest[:k])
        assert max(b - a for a, b in zip(got, got[1:], strict=False)) <= 2.4 * (hi - lo) / (k - 1)
    assert [r.params["duration"] for r in order[-3:]] == [30.0, 30.0, 30.0]  # long ones last


@pytest.mark.parametrize("override,message", [
    ("data.parameters.inlet_velocity=[0,2]", "data.parameters.inlet_velocity[0]=0.0 is invalid"),
    ("data.parameters.inlet_velocity=[2.2,1.2]", "lo <= hi"),
    ("data.metrics.lacey_block=[4,1,2]", "tile each half"),
    ("data.parameters.duration=0.015", "multiple of data.scene.snapshot_interval"),
    ("data.parameters.long.duration=2.0", "must be longer than data.parameters.duration"),
    ("data.scene.cells=[6,1]", "data.scene.cells"),
    ("data.fields.kernel_sigma=-1", "data.fields.kernel_sigma=-1 is invalid"),
    ("+data.fields.colour=1", "unknown key(s) ['colour'] in data.fields"),
])
def test_bad_values_name_the_key(tmp_path: Path, override: str, message: str):
    with pytest.raises(ConfigError) as err:
        pipeline(tmp_path, override)
    assert message in str(err.value)


def test_bad_value_ends_the_command_in_one_line(tmp_path: Path):
    proc = datagen(tmp_path, "n_sims=1", "data.parameters.inlet_velocity=[0,2]")
    assert proc.returncode == 2
    assert "data.parameters.inlet_velocity[0]=0.0 is invalid" in proc.stderr and "Traceback" not in proc.stderr


def test_openfoam_missing_or_environment_broken(tmp_path: Path):
    proc = datagen(tmp_path, "n_sims=1", env={"PATH": str(tmp_path)})
    assert proc.returncode == 2
    assert "not found on PATH" in proc.stderr and "apt-get install openfoam" in proc.stderr
    assert "Traceback" not in proc.stderr
    proc = datagen(tmp_path, "n_sims=1", env={"WM_PROJECT_DIR": str(tmp_path / "nowhere")})
    assert proc.returncode == 2 and "set WM_PROJECT_DIR" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.solver
def test_kill_mid_trajectory_and_resume(tmp_path: Path):
    env = dict(os.environ, NEURALDEM_DATA=str(tmp_path))
    proc = subprocess.Popen([sys.executable, "-m", "neuraldem", "datagen", *FAST, "n_sims=1"], cwd=REPO, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    ds = tmp_path / "datasets" / "fb_tiny"
    deadline = time.time() + 300
    while time.time() < deadline and not (ds / "runs" / "sim_0000" / "0.15").exists():
        time.sleep(0.2)  # until DPMFoam is half-way through the trajectory
    os.killpg(proc.pid, signal.SIGKILL)  # the datagen and its DPMFoam die mid-run
    proc.wait()
    assert [r.status for r in manifest(tmp_path).simulations] == ["pending"]
    again = datagen(tmp_path, "n_sims=1")
    assert again.returncode == 0, again.stderr
    assert "0 finished, 1 to run" in again.stdout + again.stderr and "1 ok" in again.stdout
    rec = manifest(tmp_path).simulations[0]
    assert rec.status == "ok"
    assert float(rec.diagnostics["resumed_from"]) >= 0.14  # DPMFoam went on from its last complete write
    attempts = json.loads((ds / "runs" / "sim_0000" / "attempts.json").read_text())
    killed = [a for a in attempts if a.get("killed")]
    assert len(killed) == 1 and killed[0]["cpu_s"] > 0  # the killed run's CPU, from its log
    assert rec.cost["attempts"] == 2 and rec.cost["solver_cpu_s"] > killed[0]["cpu_s"]
    with BedFile(ds / str(rec.file)) as f:
        assert f.n_snapshots == 21 and f.n_particles == 300
    assert not list(ds.rglob("*.partial"))


@pytest.mark.solver
def test_crashed_case_is_recorded_and_excluded_and_the_job_goes_on(tmp_path: Path):
    # a stand-in DPMFoam (test double, first on PATH) that crashes for sim_0000 and runs the real one otherwise
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    fake = bin_dir / "DPMFoam"
    fake.write_text('#!/bin/sh\ncase "$PWD" in *sim_0000*) printf "\\n--> FOAM FATAL ERROR: \\ninjected failure\\n\\n'
                    '    From somewhere\\n"; exit 1;; esac\nexec /usr/bin/DPMFoam "$@"\n')
    fake.chmod(0o755)
    path_env = {"PATH": f"{bin_dir}:{os.environ['PATH']}"}
    proc = datagen(tmp_path, "n_sims=2", env=path_env)
    assert proc.returncode == 0, proc.stderr
    m = manifest(tmp_path)
    assert [r.status for r in m.simulations] == ["failed", "ok"]  # the job went on after the crash
    failed = m.simulations[0]
    assert "FOAM FATAL ERROR: injected failure" in failed.reason and "log.DPMFoam" in failed.reason
    assert "sim_0000: failed: DPMFoam" in proc.stdout + proc.stderr
    for split in m.splits.values():
        assert "sim_0000" not in sum(split.values(), [])
    rerun = datagen(tmp_path, "n_sims=2", env=path_env)
    assert "0 to run" in rerun.stdout + rerun.stderr  # not retried by default
    # retried on request, from scratch (the failed case folder is replaced, its attempts forgotten)
    run_dir = tmp_path / "datasets" / "fb_tiny" / "runs" / "sim_0000"
    (run_dir / "leftover").write_text("x")
    retry = datagen(tmp_path, "n_sims=2", "retry_failed=true", env=path_env)
    assert retry.returncode == 0, retry.stderr
    rec = manifest(tmp_path).simulations[0]
    assert rec.status == "failed" and rec.cost["attempts"] == 1 and not (run_dir / "leftover").exists()


@pytest.mark.solver
def test_splits_keep_velocities_together_and_scene_changes_are_refused(fb_tiny_dataset: Path):
    m = Manifest.load(fb_tiny_dataset)
    parts = m.splits["velocity"]
    v_of = {r.sim_id: r.params["inlet_velocity"] for r in m.simulations}
    assert sorted(sum(parts.values(), [])) == [r.sim_id for r in m.simulations]
    train_v = {v_of[s] for s in parts["train"]}
    test_v = {v_of[s] for s in parts["test"]}
    assert train_v and test_v and not train_v & test_v  # both packings of a velocity on the same side
    assert m.splits["long"]["test"] == []
    root = fb_tiny_dataset.parent.parent
    proc = datagen(root, "n_sims=3", "data.scene.n_particles=250")
    assert proc.returncode == 2 and "different scene" in proc.stderr
    assert "fluidized_bed.n_particles" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.solver
def test_new_metric_settings_rescore_without_rerunning(fb_tiny_dataset: Path, tmp_path: Path):
    import shutil

    from neuraldem.datagen.driver import DatagenOptions, generate

    ds = tmp_path / "ds"
    shutil.copytree(fb_tiny_dataset, ds, ignore=shutil.ignore_patterns("runs"))
    before = Manifest.load(ds)
    cfg = compose_cfg("datagen", ["data=fb_tiny", "data.metrics.bubble_threshold=0.3"], output_dir=tmp_path)
    with open_dict(cfg):
        cfg.data.dataset_dir = str(ds)
    m = generate(BedPipeline(cfg.data), DatagenOptions(n_sims=3, workers=1, progress=False))
    assert m.parameters["metrics"]["bubble_threshold"] == 0.3
    for old, new in zip(before.simulations, m.simulations, strict=False):
        assert new.sha256 == old.sha256 and new.cost == old.cost  # not rerun
        assert new.metrics["bubble_fraction_mean"] >= old.metrics["bubble_fraction_mean"]
    assert any(n.metrics["bubble_fraction_mean"] > o.metrics["bubble_fraction_mean"]
               for o, n in zip(before.simulations, m.simulations, strict=False))


def test_a_long_validation_table_holds_its_long_trajectories_only(tmp_path: Path):
    """data=fb_small_longval: fb_small's scene, no regular table, one 30-s trajectory listed as validation."""
    cfg = compose_cfg("datagen", ["data=fb_small_longval"], output_dir=tmp_path)
    with open_dict(cfg):
        cfg.data.dataset_dir = str(tmp_path / "ds")
    pipe = BedPipeline(cfg.data)
    small = pipeline(tmp_path)
    assert pipe.scene.as_dict() == small.scene.as_dict()  # a model trained on fb_small is scored on it
    (only,) = pipe.parameter_sequence(1)
    assert only == {"inlet_velocity": 1.963668, "packing": 0.0, "duration": 30.0}
    m = Manifest(name="x", kind="fluidized_bed", scene={}, solver={}, parameters={})
    m.simulations = [SimRecord(sim_id=f"s{i}", index=i, params=p) for i, p in enumerate(small.parameter_sequence(93))]
    assert f"{only['inlet_velocity']:.6f}" in small.velocity_parts(m)["val"]  # a validation velocity of fb_small
    assert pipe.packing_seed(SimRecord("a", 0, {})) != small.packing_seed(SimRecord("a", 0, {}))  # a new packing
    m = Manifest(name="x", kind="fluidized_bed", scene={}, solver={}, parameters={})
    m.simulations = [SimRecord(sim_id="sim_0000", index=0, params=only, status="ok", file="sims/sim_0000.h5")]
    splits = pipe.splits(m)
    assert splits["long"] == {"train": [], "val": ["sim_0000"], "test": []}
    assert splits["velocity"] == {"train": [], "val": [], "test": []}
    with pytest.raises(ConfigError, match="n_sims=2 is invalid"):  # the table cannot grow past its long runs
        pipe.parameter_sequence(2)


@pytest.mark.parametrize("overrides,message", [
    (["data.parameters.n_velocities=0", "data.parameters.long.inlet_velocities=[]"],
     "n_velocities=0 is invalid: a table without regular velocities needs long trajectories"),
    (["data.parameters.long.part=train"], "data.parameters.long.part='train' is invalid: must be one of"),
    (["data.parameters.n_velocities=-1"], "data.parameters.n_velocities=-1 is invalid"),
])
def test_bad_long_table_values_name_the_key(tmp_path: Path, overrides: list[str], message: str):
    with pytest.raises(ConfigError) as err:
        pipeline(tmp_path, *overrides)
    assert message in str(err.value)
