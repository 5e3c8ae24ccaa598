"""Importing a user's own DPMFoam case (and a CFDEM-style case: fields + LIGGGHTS dump) gives the same file
and metrics as datagen's own conversion; damaged cases end in one line naming the file."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from neuraldem.data.manifest import Manifest
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.sim.foam_reader import FoamCase, time_dirs
from tests.helpers import run_module

pytestmark = pytest.mark.solver


def _finite(metrics: dict[str, float]) -> dict[str, float]:
    return {k: v for k, v in metrics.items() if not math.isnan(v)}


def _import(case: Path, dataset: Path, *extra: str):
    return run_module("neuraldem", "import", "foam", f"case={case}", f"dataset={dataset}", "sim_id=mine",
                      "inlet_velocity=1.5", "t0=0.05", "lacey_block=[1,1,2]", *extra)


def test_import_matches_datagen_conversion(fb_tiny_dataset: Path, fb_tiny_case: Path, tmp_path: Path):
    proc = _import(fb_tiny_case, tmp_path / "ds")
    assert proc.returncode == 0, proc.stderr
    assert "300 particles (0 lost), 21 snapshots every 0.01 s on a 6x1x15 grid (exact)" in proc.stdout
    rec = Manifest.load(tmp_path / "ds").record("mine")
    ours = Manifest.load(fb_tiny_dataset).record("sim_0000")
    assert _finite(rec.metrics) == _finite(ours.metrics)
    with BedFile(tmp_path / "ds" / str(rec.file)) as a, BedFile(fb_tiny_dataset / str(ours.file)) as b:
        for name in ("position", "displacement", "solid_fraction", "mixing", "fluid_velocity", "pressure"):
            np.testing.assert_array_equal(a._ds[name][()], b._ds[name][()])
        assert a.inlet_velocity == 1.5 and a.density == 2526.0
    again = _import(fb_tiny_case, tmp_path / "ds", "param=[packing=1]")  # same id: replaced, not added
    assert again.returncode == 0, again.stderr
    m = Manifest.load(tmp_path / "ds")
    assert len(m.simulations) == 1 and m.record("mine").params["packing"] == 1.0


def test_cfdem_style_case_with_liggghts_dump(fb_tiny_case: Path, tmp_path: Path):
    """A CFDEM run keeps its particles in LIGGGHTS and its fluid as voidfraction/U: build one from the
    DPMFoam case (the same numbers under CFDEM's names) and import it."""
    case = tmp_path / "CFD"
    shutil.copytree(fb_tiny_case, case, ignore=shutil.ignore_patterns("lagrangian", "postProcessing"))
    dem_dt = 1e-5
    frames = []
    src = FoamCase(fb_tiny_case)
    for value, name in time_dirs(case):
        if value <= 0:
            continue
        (case / name / "alpha.air").rename(case / name / "voidfraction")
        (case / name / "U.air").rename(case / name / "U")
        snap = src.cloud(name)
        assert snap.velocities is not None
        rows = "".join(f"{i + 1} " + " ".join(repr(float(v)) for v in (*p, *u, d / 2)) + "\n" for i, p, u, d in
                       zip(snap.orig_id.tolist(), snap.positions, snap.velocities, snap.diameters, strict=False))
        frames.append(f"ITEM: TIMESTEP\n{round(value / dem_dt)}\nITEM: NUMBER OF ATOMS\n{len(snap)}\n"
                      "ITEM: BOX BOUNDS ff ff ff\n0 0.024\n0 0.006\n0 0.06\n"
                      f"ITEM: ATOMS id x y z vx vy vz radius\n{rows}")
    (tmp_path / "dump.liggghts").write_text("".join(frames))
    proc = run_module("neuraldem", "import", "foam", f"case={case}", f"dataset={tmp_path / 'ds'}", "sim_id=cfdem",
                      "inlet_velocity=1.5", "t0=0.05", "fluid_fraction=voidfraction", "fluid_velocity=U",
                      f"liggghts_dump={tmp_path / 'dump.liggghts'}", f"dem_dt={dem_dt}", "lacey_block=[1,1,2]")
    assert proc.returncode == 0, proc.stderr
    direct = _import(fb_tiny_case, tmp_path / "ref")
    assert direct.returncode == 0, direct.stderr
    with BedFile(tmp_path / "ds" / "sims" / "cfdem.h5") as a, BedFile(tmp_path / "ref" / "sims" / "mine.h5") as b:
        np.testing.assert_array_equal(a.positions(), b.positions())
        np.testing.assert_array_equal(a.solid_fraction(), b.solid_fraction())
        np.testing.assert_array_equal(a.fluid_velocity(), b.fluid_velocity())
        np.testing.assert_array_equal(a.orig_id, b.orig_id + 1)  # LIGGGHTS ids


def test_missing_cell_centres_are_written(fb_tiny_case: Path, tmp_path: Path):
    case = tmp_path / "case"
    shutil.copytree(fb_tiny_case, case)
    for name in ("C", "Cx", "Cy", "Cz"):
        (case / "0" / name).unlink(missing_ok=True)
    proc = _import(case, tmp_path / "ds", "snapshots=3")
    assert proc.returncode == 0, proc.stderr
    assert (case / "0" / "C").is_file() and "3 snapshots" in proc.stdout


def test_damaged_or_wrong_cases_end_in_one_line(fb_tiny_case: Path, tmp_path: Path):
    case = tmp_path / "case"
    shutil.copytree(fb_tiny_case, case)
    alpha = case / "0.12" / "alpha.air"
    alpha.write_text(alpha.read_text()[:900])  # a time directory cut short (full disk, killed write)
    proc = _import(case, tmp_path / "ds")
    assert proc.returncode == 2 and str(alpha) in proc.stderr and "truncated" in proc.stderr
    assert "Traceback" not in proc.stderr
    wrong_cloud = _import(fb_tiny_case, tmp_path / "ds", "cloud=sprayCloud")
    assert wrong_cloud.returncode == 2 and "is cloud= right?" in wrong_cloud.stderr
    bad = _import(fb_tiny_case, tmp_path / "ds", "dt_ml=-1")
    assert bad.returncode == 2 and "dt_ml= must be positive" in bad.stderr
    assert not (tmp_path / "ds" / "manifest.json").exists()


def test_a_bed_checkpoint_rolls_out_on_imported_cases_of_its_scene(fb_tiny_case: Path, fb_tiny_checkpoint: Path,
                                                                    tmp_path: Path):
    assert _import(fb_tiny_case, tmp_path / "ds").returncode == 0
    scene = Manifest.load(tmp_path / "ds").scene["fluidized_bed"]
    assert scene["cells"] == [6, 1, 15] and scene["snapshot_interval"] == pytest.approx(0.01)
    proc = run_module("neuraldem", "evaluate", f"ckpt={fb_tiny_checkpoint}", f"dataset_dir={tmp_path / 'ds'}",
                      "vtk=false", "fluidized_bed.horizons=[1]", f"hydra.run.dir={tmp_path / 'eval'}")
    assert proc.returncode == 0, proc.stderr
    result = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert result["split"] == "imported (every run)" and [t["sim_id"] for t in result["trajectories"]] == ["mine"]
    # particles of another density: another bed, refused naming the key (and a second case cannot join)
    assert _import(fb_tiny_case, tmp_path / "other", "density=3000").returncode == 0
    proc = run_module("neuraldem", "evaluate", f"ckpt={fb_tiny_checkpoint}", f"dataset_dir={tmp_path / 'other'}",
                      "vtk=false", f"hydra.run.dir={tmp_path / 'eval2'}")
    assert proc.returncode == 2 and "fluidized_bed.density: trained 2526.0, imported 3000.0" in proc.stderr
    proc = _import(fb_tiny_case, tmp_path / "ds", "density=3000")
    assert proc.returncode == 2 and "holds imported runs of another bed" in proc.stderr
