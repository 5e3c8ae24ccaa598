"""Importing a user's own LIGGGHTS dump gives the same file and metrics as datagen's own conversion."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from neuraldem.data.hopper_store import HopperFile, write_hopper_file
from neuraldem.data.manifest import Manifest
from neuraldem.datagen.hopper import stored_metrics
from neuraldem.sim.hopper import HopperScene, run_hopper
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


def _import(workdir: Path, dataset: Path, res, open_step: int, *extra: str):
    g = res.trajectory.geometry
    return run_module("neuraldem.import_liggghts", "--dump", str(workdir / "dump.txt"), "--exits",
                      str(workdir / "exits.txt"), "--dataset", str(dataset), "--sim-id", "mine", "--dt", "1e-4",
                      "--open-step", str(open_step), "--diameter", "0.01", "--radius", str(g.radius),
                      "--outlet-radius", str(g.outlet_radius), "--cone-height", str(g.cone_height),
                      "--sink-z", str(g.sink_z), "--param", "alpha=40", "--param", "mu_s=0.4",
                      "--param", "mu_r=0.1", *extra)


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
    proc = _import(cut, tmp_path / "ds", res, open_step, "--drop-truncated-tail")
    assert proc.returncode == 0, proc.stderr
