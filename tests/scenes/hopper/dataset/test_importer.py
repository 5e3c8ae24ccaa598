"""Importing a user's own LIGGGHTS dump gives the same file and metrics as datagen's own conversion, records
its scene, and a checkpoint of that scene scores it (another scene is refused naming the keys). A run datagen
made, imported with its scene, reads the generated metrics bit for bit (a run that drained early holds its final
state up to the horizon), and `evaluate` scores it as it scores the generated run, every row against one truth.
A dump that does not fit the stated hopper is refused in one line."""

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
               "outlet_radius": g.outlet_radius, "cone_height": g.cone_height, "sink_z": g.sink_z, "max_time": 5,
               "param": "[alpha=40,mu_s=0.4,mu_r=0.1]", **changed}
    return run_module("neuraldem", "import", "liggghts", *(f"{k}={v}" for k, v in options.items() if v is not None))


def test_import_matches_datagen_conversion(liggghts_run, tmp_path: Path):
    workdir, res, open_step = liggghts_run
    proc = _import(workdir, tmp_path / "ds", res, open_step)
    assert proc.returncode == 0, proc.stderr
    rec = Manifest.load(tmp_path / "ds").record("mine")
    # datagen's own conversion of the same run: write, then score what was stored
    write_hopper_file(tmp_path / "datagen.h5", "mine", res.trajectory, {}, "test", 1e-5)
    assert rec.metrics == stored_metrics(tmp_path / "datagen.h5", 0.01, horizon=5.0)  # the scene's horizon
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


@pytest.mark.parametrize(("changed", "expected"), [
    ({"radius": 0.05, "param": "[mu_s=0.4,mu_r=0.1]"},
     "particle centres lie outside the stated hopper radius 0.05 m, the farthest"),
    ({"radius": 0.10, "param": "[mu_s=0.4,mu_r=0.1]"}, "the stated hopper radius 0.1 m is"),
    ({"cone_height": 0.0, "param": "[mu_s=0.4,mu_r=0.1]"}, "above the stated cone (height 0 m at the wall)"),
    ({"cone_height": 0.12}, "cone_height=0.12 differs from the cone of alpha=40"),
    ({"cone_height": 0.08, "param": "[mu_s=0.4,mu_r=0.1]"}, "particle centres lie below the stated cone"),
    ({"cone_height": None, "param": "[mu_s=0.4,mu_r=0.1]"}, "cone_height= is needed"),
    ({"max_time": None}, "give max_time= (the horizon every run is scored over"),
])
def test_a_dump_that_does_not_fit_the_stated_hopper_is_one_line(liggghts_run, tmp_path: Path, changed, expected):
    workdir, res, open_step = liggghts_run
    proc = _import(workdir, tmp_path / "ds", res, open_step, **changed)
    assert proc.returncode == 2 and expected in proc.stderr, proc.stderr
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert not (tmp_path / "ds" / "manifest.json").exists()


@pytest.fixture(scope="module")
def raw_dataset(data_root: Path) -> Path:
    """hopper_tiny generated again with its raw LIGGGHTS files kept (no characterization): the same 8 runs,
    their dumps beside them (resumable: reused when NEURALDEM_TEST_DATA is set)."""
    from omegaconf import open_dict

    from neuraldem.datagen.driver import DatagenOptions, generate
    from neuraldem.scenes.hopper.dataset.datagen import HopperPipeline
    from tests.helpers import compose_cfg

    cfg = compose_cfg("datagen", ["data=hopper_tiny", "data.name=hopper_tiny_raw", "data.storage.keep_raw=true",
                                  "data.characterization.enabled=false"], output_dir=data_root / "runs")
    with open_dict(cfg):
        cfg.data.dataset_dir = str(data_root / "datasets" / "hopper_tiny_raw")
    m = generate(HopperPipeline(cfg.data), DatagenOptions(n_sims=8, workers=1, progress=False))
    assert all(r.status == "ok" for r in m.simulations), [(r.sim_id, r.status, r.reason) for r in m.simulations]
    return Path(cfg.data.dataset_dir)


def _import_generated(raw: Path, sim_id: str, dataset: Path, *extra: str):
    rec = Manifest.load(raw).record(sim_id)
    run = raw / "runs" / sim_id
    params = ",".join(f"{k}={v!r}" for k, v in rec.params.items())
    return rec, run_module("neuraldem", "import", "liggghts", f"dump={run / 'dump.txt'}", f"exits={run / 'exits.txt'}",
                           f"scene={raw}", f"dataset={dataset}", f"sim_id={sim_id}", f"param=[{params}]", *extra)


def test_a_generated_run_imported_reads_the_generated_metrics(raw_dataset: Path, tmp_path: Path):
    """Only the dump, the exit file and the scene: the opening step and sink come from our deck beside the dump,
    the geometry from the scene and alpha; the run drained long before the 5-s horizon and holds its final
    state, so residual and drainage time are datagen's, bit for bit."""
    for sim_id in ("sim_0001", "sim_0007"):
        rec, proc = _import_generated(raw_dataset, sim_id, tmp_path / "mine")
        assert proc.returncode == 0, proc.stderr
        assert "its final state held from" in proc.stdout and "to the horizon 5 s" in proc.stdout
        mine = Manifest.load(tmp_path / "mine").record(sim_id)
        assert mine.metrics == rec.metrics and mine.metrics["residual_fraction"] == 0.0
        assert mine.diagnostics["open_step"] == 3000
    # scored over the run's own length instead (what a horizon-less import did): residual and t95 are off
    own = stored_metrics(tmp_path / "mine" / "sims" / "sim_0007.h5", 0.01)
    assert own["residual_fraction"] > 0.1 and own["drainage_t95"] < 0.9 * rec.metrics["drainage_t95"]


def test_evaluate_scores_an_imported_run_as_the_generated_one(raw_dataset: Path, tiny_checkpoint: Path,
                                                              tmp_path: Path):
    """The checkpoint's test run evaluated in the generated dataset and imported alone into a dataset of its own:
    the same numbers in every row (field model, GP, constant), the baselines fitted on the same runs."""
    from neuraldem.scenes.hopper.analysis.evaluation import evaluate_checkpoint

    datasets = tmp_path / "datasets"  # where the imported evaluation finds the training runs of the baselines
    datasets.mkdir()
    (datasets / "hopper_tiny").symlink_to(raw_dataset)
    generated = evaluate_checkpoint(tiny_checkpoint, tmp_path / "gen", datasets, raw_dataset, vtk=False,
                                    progress=False)
    test_id = generated["simulations"][0]["sim_id"]
    assert [s["sim_id"] for s in generated["simulations"]] == [test_id]
    _, proc = _import_generated(raw_dataset, test_id, tmp_path / "mine")
    assert proc.returncode == 0, proc.stderr
    imported = evaluate_checkpoint(tiny_checkpoint, tmp_path / "imp", datasets, tmp_path / "mine", vtk=False,
                                   progress=False)

    def errors(agg: dict) -> dict:
        return {k: v for k, v in agg.items() if k not in ("answer_s", "fit_s")}

    assert errors(imported["aggregate"]) == errors(generated["aggregate"])
    for kind in ("gp", "constant"):
        assert errors(imported["baselines"][kind]["aggregate"]) == errors(generated["baselines"][kind]["aggregate"])
    assert imported["truth"].startswith("every row against the DEM fields")


def test_one_dataset_scores_every_run_over_one_horizon(liggghts_run, tmp_path: Path):
    workdir, res, open_step = liggghts_run
    assert _import(workdir, tmp_path / "ds", res, open_step).returncode == 0
    assert Manifest.load(tmp_path / "ds").scene["hopper"]["max_time"] == 5
    again = _import(workdir, tmp_path / "ds", res, open_step, sim_id="other", max_time=None)  # the dataset's
    assert again.returncode == 0, again.stderr
    other = _import(workdir, tmp_path / "ds", res, open_step, sim_id="third", max_time=3)
    assert other.returncode == 2 and "scores its runs over max_time=5 s, this run would be scored over 3 s" in \
        other.stderr, other.stderr
