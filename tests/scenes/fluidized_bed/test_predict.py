"""`neuraldem predict fb`: the bed's what-if from a shipped model (tiny, plumbing only), --verify with DPMFoam,
and bad input in one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import run_module


def predict(*args: str, env: dict[str, str] | None = None):
    return run_module("neuraldem", "predict", *args, env=env)


def test_bed_answers_fields_animation_and_verify(fb_tiny_pretrained: Path, tmp_path: Path):
    env = {"NEURALDEM_PRETRAINED_DIR": str(fb_tiny_pretrained)}
    proc = predict("fb", "inlet_velocity=1.5", "--verify", "--out", str(tmp_path), env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "| bed height (mean) [mm] |" in proc.stdout and "| Lacey index after 0.1 s |" in proc.stdout
    assert "held-out CFD-DEM runs (meta.json)" in proc.stdout and "GP vs DPMFoam: bed height" in proc.stdout
    answer = json.loads((tmp_path / "answer.json").read_text())
    gp = answer["gp"]
    for key in ("bed_height", "bubble_fraction", "lacey"):
        assert gp["low"][key] <= gp["mean"][key] <= gp["high"][key], key
    truth = answer["dpmfoam"]["answers"]
    assert answer["dpmfoam"]["status"] == "ok" and 0.005 < truth["bed_height"] < 0.06
    assert answer["field"]["steps"] == 19 and np.isfinite(answer["field"]["summary"]["bed_height"])
    for name in ("curves.png", "animation.gif", "vtk/bed_predicted_grid.pvd"):
        assert (tmp_path / name).stat().st_size > 0, name
    # the numbers are printed before the pictures are drawn; answer.json then names them
    assert proc.stdout.index("numbers in") < proc.stdout.index("picture(s) and ParaView series")
    assert answer["field"]["files"] == {"animation": str(tmp_path / "animation.gif"), "vtk": str(tmp_path / "vtk")}
    bare = predict("fb", "inlet_velocity=1.5", "pictures=false", f"out={tmp_path / 'bare'}", env=env)
    assert bare.returncode == 0 and "picture(s)" not in bare.stdout, bare.stderr
    assert sorted(p.name for p in (tmp_path / "bare").iterdir()) == ["answer.json"]
    # the same inputs again: the finished DPMFoam check is read back, not rerun
    again = predict("fb", "inlet_velocity=1.5", "--verify", "--no-fields", "--out", str(tmp_path), env=env)
    assert again.returncode == 0 and "DPMFoam answer read back" in again.stderr, again.stderr


def test_the_bed_answer_equals_its_scalar_model_and_the_build_scores_the_predict_path(fb_tiny_pretrained: Path,
                                                                                       tmp_path: Path):
    from neuraldem import pretrained
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess

    env = {"NEURALDEM_PRETRAINED_DIR": str(fb_tiny_pretrained)}
    proc = predict("fb", "inlet_velocity=1.3", "--no-fields", "--json", "--out", str(tmp_path), env=env)
    assert proc.returncode == 0, proc.stderr
    printed = json.loads(proc.stdout)
    model = pretrained.Pretrained("fb_tiny_test", fb_tiny_pretrained / "fb_tiny_test",
                                  json.loads((fb_tiny_pretrained / "fb_tiny_test" / "meta.json").read_text()))
    expected = ArrayGaussianProcess.load_npz(model.file("gp")).predict([[1.3]])[0]
    assert printed["gp"]["mean"] == pytest.approx(expected.mean) and "field" not in printed
    errors = model.meta["test_errors"]
    run = errors["runs"][0]  # the stored error is |rollout answer - CFD-DEM answer| of the predict path
    assert errors["field model"]["bed_height_mae_mm"] == pytest.approx(
        1000 * abs(run["field model"]["bed_height"] - run["cfd_dem"]["bed_height"]))
    assert set(model.meta["files"]) == {"field", "gp", "states"}


def test_bed_what_if_bad_input(fb_tiny_pretrained: Path, tmp_path: Path):
    env = {"NEURALDEM_PRETRAINED_DIR": str(fb_tiny_pretrained)}
    far = predict("fb", "inlet_velocity=3.5", "--no-fields", "--out", str(tmp_path), env=env)
    assert far.returncode == 0 and "inlet_velocity=3.5 is outside the trained range" in far.stderr, far.stderr
    for args, expected in ((("fb", "velocity=1.5"), "unknown option velocity=: the options are inlet_velocity="),
                           (("fb", "inlet_velocity=-1"), "outside what the solver can run"),
                           (("fb", "inlet_velocity=1.5", "threads=0"), "threads=0 is invalid: give a whole number"),
                           (("fb", "inlet_velocity=1.5", "runtime=gpu"), "option runtime=: invalid choice: 'gpu'")):
        proc = predict(*args, "--out", str(tmp_path), env=env)
        out = proc.stdout + proc.stderr
        assert proc.returncode == 2 and expected in out and "Traceback" not in out, out
    broken = tmp_path / "models"
    import shutil

    shutil.copytree(fb_tiny_pretrained, broken)
    (broken / "fb_tiny_test" / "states.npz").write_bytes(b"damaged")
    proc = predict("fb", "inlet_velocity=1.5", "--out", str(tmp_path / "o"),
                   env={"NEURALDEM_PRETRAINED_DIR": str(broken)})
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2 and "states.npz is damaged" in out and "rebuild" in out, out


@pytest.mark.parametrize("shipped", [False, True], ids=["tiny", "fb_small"])
def test_the_shipped_bed_files_reproduce_their_stored_probe_answers(fb_tiny_pretrained: Path, shipped: bool):
    """Loaded back, a model's files answer its probe velocities as when it was built: the GP exactly, the
    field model's rollout (seed 0, from the shipped state) to round-off on this CPU."""
    from neuraldem import pretrained
    from neuraldem.eval.checkpoints import read_checkpoint
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess
    from neuraldem.scenes.fluidized_bed.predict import fb_settings, fb_window
    from neuraldem.scenes.fluidized_bed.whatif import InitialStates, field_answer

    if shipped:
        model = pretrained.load("fb_small", "fluidized_bed")
    else:
        folder = fb_tiny_pretrained / "fb_tiny_test"
        model = pretrained.Pretrained("fb_tiny_test", folder, json.loads((folder / "meta.json").read_text()))
    gp = ArrayGaussianProcess.load_npz(model.file("gp"))
    for probe in model.meta["probes"]:
        v = probe["parameters"]["inlet_velocity"]
        assert gp.predict([[v]])[0].mean == pytest.approx(probe["gp_mean"], rel=1e-9)
    probe = next(p for p in model.meta["probes"] if "field_summary" in p)
    module = read_checkpoint(model.file("field")).module("fluidized_bed", "cpu", "test")
    f = field_answer(module, InitialStates.load_npz(model.file("states")), probe["parameters"]["inlet_velocity"],
                     fb_settings(model), fb_window(model))
    # the tiny model's 19 steps reproduce to round-off; fb_small's 299 chaotic steps are allowed a few %, since
    # another CPU's float kernels may differ in the last bits (a wrong model file misses by far more)
    assert f.summary == pytest.approx(probe["field_summary"], rel=0.05 if shipped else 1e-4, abs=1e-6)


def test_refresh_field_reruns_the_field_answers_and_keeps_the_rest(fb_tiny_pretrained: Path, tmp_path: Path):
    """After a change of the rollout code: the field answers of the test rows and the probe are rerun from the
    shipped states (stale values are replaced, errors recomputed against the stored CFD-DEM answers), the
    files, the GP answers and CFD-DEM's stay as they were, and the refresh is recorded."""
    import shutil

    from neuraldem.scenes.fluidized_bed.release import errors

    folder = tmp_path / "fb_tiny_test"
    shutil.copytree(fb_tiny_pretrained / "fb_tiny_test", folder)
    meta = json.loads((folder / "meta.json").read_text())
    fresh = meta["test_errors"]["runs"][0]["field model"]
    stale = json.loads(json.dumps(meta))
    stale["test_errors"]["runs"][0]["field model"] = {k: v + 1.0 for k, v in fresh.items()}
    next(p for p in stale["probes"] if "field_summary" in p)["field_summary"]["lacey"] = 9.0
    (folder / "meta.json").write_text(json.dumps(stale))
    proc = run_module("neuraldem.release", "fluidized_bed", "name=fb_tiny_test", f"out={tmp_path}",
                      "refresh_field=true")
    assert proc.returncode == 0, proc.stderr
    new = json.loads((folder / "meta.json").read_text())
    assert new["test_errors"]["runs"][0]["field model"] == pytest.approx(fresh, rel=1e-4, abs=1e-6)
    assert next(p for p in new["probes"] if "field_summary" in p)["field_summary"]["lacey"] != 9.0
    runs = new["test_errors"]["runs"]
    assert new["test_errors"]["field model"] == errors([r["field model"] for r in runs], [r["cfd_dem"] for r in runs])
    assert new["files"] == meta["files"] and new["training_data"] == meta["training_data"]
    assert [p["gp_mean"] for p in new["probes"]] == [p["gp_mean"] for p in meta["probes"]]
    assert [r["cfd_dem"] for r in runs] == [r["cfd_dem"] for r in meta["test_errors"]["runs"]]
    assert new["refreshed"][-1]["field_model_errors_before"] == stale["test_errors"]["field model"]


@pytest.mark.parametrize("flags,message", [(["refresh_field=true"], "meta.json is missing"),
                                           ([], "ckpt= is required")])
def test_refresh_bad_input_ends_in_one_line(tmp_path: Path, flags: list[str], message: str):
    proc = run_module("neuraldem.release", "fluidized_bed", "name=nothing_here", f"out={tmp_path}", *flags)
    assert proc.returncode != 0 and message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


def test_refresh_with_rollout_options_writes_them_into_the_shipped_model(fb_tiny_pretrained: Path, tmp_path: Path):
    """rollout.rollout_noise= / rollout.advection_correction= are written into field.pt (so predict, the explorer
    and evaluate roll out with them without an option), its checksum in meta.json follows and the options are
    recorded; a value out of range is refused in one line before the file is touched."""
    import shutil

    from neuraldem.data.integrity import digest
    from neuraldem.eval.checkpoints import read_checkpoint
    from neuraldem.scenes.fluidized_bed.surrogate.rollout import ModelStepper

    folder = tmp_path / "fb_tiny_test"
    shutil.copytree(fb_tiny_pretrained / "fb_tiny_test", folder)
    field = folder / "field.pt"
    before = digest(field)
    release = ("neuraldem.release", "fluidized_bed", "name=fb_tiny_test", f"out={tmp_path}", "refresh_field=true")
    bad = run_module(*release, "rollout.rollout_noise=-1")
    assert bad.returncode == 2 and "Traceback" not in bad.stderr, bad.stderr
    assert bad.stderr.strip() == ("neuraldem: error: rollout.rollout_noise=-1 is invalid: must be a number in [0, 10] "
                                  "(e.g. rollout.rollout_noise=3)")
    assert digest(field) == before
    proc = run_module(*release, "rollout.rollout_noise=2", "rollout.advection_correction=1")
    assert proc.returncode == 0, proc.stderr
    meta = json.loads((folder / "meta.json").read_text())
    assert meta["rollout_options"] == {"rollout_noise": 2.0, "advection_correction": 1.0, "mirror_alternate": False}
    assert meta["files"]["field"]["sha256"] == digest(field) != before
    assert "rollout options" in meta["refreshed"][-1]["what"]
    assert meta["rebuild"][-1].endswith("refresh_field=true rollout.advection_correction=1 "
                                        "rollout.mirror_alternate=false rollout.rollout_noise=2")
    stepper = ModelStepper(read_checkpoint(field).module("fluidized_bed", "cpu", "test"), 1.5)
    assert stepper.stability.rollout_noise == 2.0 and stepper.stability.advection_correction == 1.0
    assert stepper.noise_std is not None


def test_the_field_answer_imports_no_lightning_no_datagen(fb_tiny_pretrained: Path, tmp_path: Path):
    """What the answer does not need stays off its path: Lightning (~1.3 s), the datagen and scipy.stats."""
    code = ("import sys; from neuraldem.__main__ import main; "
            f"main(['predict', 'fluidized_bed', 'inlet_velocity=1.5', 'pictures=false', 'out={tmp_path}']); "
            "print(sorted(m for m in ('lightning', 'scipy.stats', 'neuraldem.scenes.fluidized_bed.dataset.datagen', "
            "'neuraldem.scenes.fluidized_bed.surrogate.module') if m in sys.modules))")
    env = {**os.environ, "NEURALDEM_PRETRAINED_DIR": str(fb_tiny_pretrained)}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "| bed height (mean) [mm] |" in proc.stdout and proc.stdout.strip().endswith("[]"), proc.stdout
