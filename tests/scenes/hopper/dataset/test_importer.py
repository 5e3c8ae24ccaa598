"""Importing a user's own LIGGGHTS dump gives the same file and metrics as datagen's own conversion, records
its scene, and a checkpoint of that scene scores it (another scene is refused naming the keys)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from neuraldem.data.manifest import Manifest
from neuraldem.eval.checkpoints import imported_scene_differences
from neuraldem.scenes.hopper.dataset.datagen import stored_metrics
from neuraldem.scenes.hopper.dataset.store import HopperFile, write_hopper_file
from neuraldem.scenes.hopper.solver import HopperScene, run_hopper
from tests.helpers import REPO, run_module

pytestmark = pytest.mark.solver


@pytest.fixture(scope="module")
def liggghts_run(tmp_path_factory):
    cfg = OmegaConf.merge(OmegaConf.load(REPO / "conf/data/hopper_small.yaml").scene,
                          OmegaConf.load(REPO / "conf/data/hopper_tiny.yaml").scene)
    scene = HopperScene.from_config(cfg, "data.scene")
    workdir = tmp_path_factory.mktemp("user_run")
    res = run_hopper(scene, 40.0, 0.4, 0.1, workdir, index=3)
    assert res.status == "ok"
    open_step = next(int(line.split()[1]) for line in res.solver.log.splitlines()
                     if line.startswith("NEURALDEM_OPEN_STEP"))
    return workdir, res, open_step


def _import(workdir: Path, dataset: Path, res, open_step: int, **changed: str):
    """`neuraldem import liggghts` of the run; `changed` replaces or adds options (each key is given once)."""
    g = res.trajectory.geometry
    options = {"dump": workdir / "dump.txt", "exits": workdir / "exits.txt", "dataset": dataset, "sim_id": "mine",
               "dt": "1e-4", "open_step": open_step, "diameter": "0.01", "radius": g.radius,
               "outlet_radius": g.outlet_radius, "cone_height": g.cone_height, "sink_z": g.sink_z,
               "param": "[alpha=40,mu_s=0.4,mu_r=0.1]", **changed}
    return run_module("neuraldem", "import", "liggghts", *(f"{k}={v}" for k, v in options.items()))


def test_import_matches_datagen_conversion(liggghts_run, tmp_path: Path):
    workdir, res, open_step = liggghts_run
    proc = _import(workdir, tmp_path / "ds", res, open_step)
    assert proc.returncode == 0, proc.stderr
    rec = Manifest.load(tmp_path / "ds").record("mine")
    # datagen's own conversion of the same run: write, then score what was stored
    write_hopper_file(tmp_path / "datagen.h5", "mine", res.trajectory, {}, "test", 1e-5)
    assert rec.metrics == stored_metrics(tmp_path / "datagen.h5", 0.01)
    with HopperFile(tmp_path / "ds" / rec.file) as f:
        np.testing.assert_allclose(f.positions(), res.trajectory.positions, atol=1e-5)


def test_truncated_user_dump(liggghts_run, tmp_path: Path):
    workdir, res, open_step = liggghts_run
    cut = tmp_path / "run"
    cut.mkdir()
    text = (workdir / "dump.txt").read_text()
    (cut / "dump.txt").write_text(text[: int(len(text) * 0.7)])
    (cut / "exits.txt").write_text((workdir / "exits.txt").read_text())
    proc = _import(cut, tmp_path / "ds", res, open_step)
    assert proc.returncode == 2 and "truncated" in proc.stderr and "dump.txt: frame" in proc.stderr
    assert "Traceback" not in proc.stderr
    proc = _import(cut, tmp_path / "ds", res, open_step, drop_truncated_tail="true")
    assert proc.returncode == 0, proc.stderr


def test_import_records_the_scene_and_keeps_one_scene_per_dataset(liggghts_run, tmp_path: Path):
    workdir, res, open_step = liggghts_run
    assert _import(workdir, tmp_path / "ds", res, open_step).returncode == 0
    scene = Manifest.load(tmp_path / "ds").scene
    g = res.trajectory.geometry
    assert scene["imported"] and scene["hopper"]["material"] == {"diameter": 0.01, "dt": 1e-4}
    assert scene["hopper"]["hopper_diameter"] == pytest.approx(2 * g.radius)
    proc = _import(workdir, tmp_path / "ds", res, open_step, diameter="0.02")
    assert proc.returncode == 2 and "holds imported runs of another scene" in proc.stderr
    assert "hopper.material.diameter: trained 0.01, imported 0.02" in proc.stderr


def test_a_checkpoint_scores_imported_runs_of_its_scene(liggghts_run, tiny_checkpoint: Path, tmp_path: Path):
    workdir, res, open_step = liggghts_run
    assert _import(workdir, tmp_path / "ds", res, open_step).returncode == 0
    proc = run_module("neuraldem", "evaluate", f"ckpt={tiny_checkpoint}", f"dataset_dir={tmp_path / 'ds'}",
                      "vtk=false", f"hydra.run.dir={tmp_path / 'eval'}")
    assert proc.returncode == 0, proc.stderr
    result = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert result["split"] == "imported (every run)" and result["aggregate"]["n_sims"] == 1
    assert "aggregate" in result["baselines"]["constant"]  # fitted on the checkpoint's own training runs
    # another particle size: refused, naming the key and both values
    assert _import(workdir, tmp_path / "other", res, open_step, diameter="0.012").returncode == 0
    proc = run_module("neuraldem", "evaluate", f"ckpt={tiny_checkpoint}", f"dataset_dir={tmp_path / 'other'}",
                      "vtk=false", f"hydra.run.dir={tmp_path / 'eval2'}")
    assert proc.returncode == 2 and "trained on another scene" in proc.stderr
    assert "hopper.material.diameter: trained 0.01, imported 0.012" in proc.stderr and "Traceback" not in proc.stderr
    # a run without a scalar the model is conditioned on: one line naming it
    m = Manifest.load(tmp_path / "ds")
    m.simulations[0].params.pop("mu_r")
    m.save(tmp_path / "ds")
    proc = run_module("neuraldem", "evaluate", f"ckpt={tiny_checkpoint}", f"dataset_dir={tmp_path / 'ds'}",
                      "vtk=false", f"hydra.run.dir={tmp_path / 'eval3'}")
    assert proc.returncode == 2 and "lacks mu_r" in proc.stderr and "param=[mu_r=VALUE]" in proc.stderr


def test_scene_differences_within_the_stated_tolerance():
    trained = {"hopper": {"hopper_diameter": 0.14, "outlet_diameter": 0.07, "material": {"diameter": 0.01}}}
    close = {"hopper": {"hopper_diameter": 0.1405, "outlet_diameter": 0.07, "material": {"diameter": 0.01}}}
    assert imported_scene_differences("hopper", trained, close) == []  # 0.36 % < 1 %
    far = {"hopper": {"hopper_diameter": 0.15, "outlet_diameter": 0.07, "material": {}}}
    assert imported_scene_differences("hopper", trained, far) == [
        "hopper.hopper_diameter: trained 0.14, imported 0.15", "hopper.material.diameter: trained 0.01, imported None"]
