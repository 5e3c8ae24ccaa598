"""`neuraldem predict`: a what-if answer from the shipped model, its outputs, verify=true, and bad input in one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.helpers import run_module


def predict(*args: str, env: dict[str, str] | None = None):
    return run_module("neuraldem", "predict", *args, env=env)


def one_line_error(proc) -> str:
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2 and "Traceback" not in out, out
    return out


def test_answers_with_intervals_fields_stripes_and_vtk(tmp_path: Path):
    proc = predict("hopper", "alpha=40", "mu_s=0.3", "mu_r=0.1", "time_stride=6", f"out={tmp_path}")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "| drainage t95 [s] |" in proc.stdout and "| flow regime |" in proc.stdout
    assert "held-out LIGGGHTS runs (meta.json): GP t95" in proc.stdout  # how far to trust it, beside it
    answer = json.loads((tmp_path / "answer.json").read_text())
    gp = answer["gp"]
    for key in ("drainage_t95", "residual_fraction", "outflow_rate", "mass_flow_index"):
        assert gp["low"][key] <= gp["mean"][key] <= gp["high"][key], key
    from neuraldem.scenes.hopper.whatif import ANSWER_BUDGET

    assert answer["field"]["budget"] == ANSWER_BUDGET.as_dict() and answer["field"]["runtime"] == "onnx"
    assert answer["field"]["n_points"] > 200 and 0.5 < answer["field"]["summary"]["drainage_t95"] < 15
    assert (tmp_path / "stripes.png").stat().st_size > 0
    assert (tmp_path / "vtk" / "hopper_predicted.pvd").is_file()
    assert not answer["warnings"]


def test_the_gp_answer_equals_the_shipped_gp(tmp_path: Path):
    from neuraldem import pretrained
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess

    proc = predict("hopper", "alpha=25", "mu_s=0.6", "mu_r=0.3", "fields=false", "json=true", f"out={tmp_path}")
    assert proc.returncode == 0, proc.stderr
    printed = json.loads(proc.stdout)
    gp = ArrayGaussianProcess.load_npz(pretrained.load("hopper_small").file("gp"))
    expected = gp.predict([[25.0, 0.6, 0.3]])[0]
    assert printed["gp"]["mean"] == pytest.approx(expected.mean) and "field" not in printed


def test_outside_the_trained_range_answers_with_a_warning(tmp_path: Path):
    proc = predict("hopper", "alpha=70", "mu_s=0.3", "mu_r=0.1", "fields=false", f"out={tmp_path}")
    assert proc.returncode == 0, proc.stderr
    assert "alpha=70 is outside the trained range" in proc.stderr and "59." in proc.stderr
    assert "| drainage t95 [s] |" in proc.stdout


@pytest.mark.parametrize(("args", "expected"), [
    (("drum", "x=1"), "unknown scene 'drum': choose one of: hopper, hopper_refill, fluidized_bed / bed / fb"),
    (("hopper", "alpha=40", "mu_s=0.3", "phi=2"), "unknown option phi=: the options are alpha=, mu_s=, mu_r="),
    (("hopper", "alpha=40", "mu_s=0.3"), "missing hopper parameter(s) mu_r"),
    (("hopper", "alpha=90", "mu_s=0.3", "mu_r=0.1"), "alpha=90 is outside what the solver can run (0 .. 75)"),
    (("hopper", "alpha=forty", "mu_s=0.3", "mu_r=0.1"), "alpha='forty' is not a number"),
    (("hopper", "alpha=40", "mu_s=0.3", "mu_r=0.1", "model=nope"), "unknown pretrained model 'nope'"),
    (("hopper", "alpha=40", "alpha=41", "mu_s=0.3", "mu_r=0.1"), "alpha= is given twice: give each option once"),
])
def test_bad_input_is_one_line(args: tuple[str, ...], expected: str, tmp_path: Path):
    out = one_line_error(predict(*args, f"out={tmp_path}"))
    assert expected in out and out.startswith("neuraldem: error: ") and out.count("\n") == 1


def test_a_damaged_shipped_file_names_it_and_the_rebuild(tmp_path: Path):
    import shutil

    from neuraldem import pretrained
    from tests.helpers import flip_byte

    folder = tmp_path / "models"
    shutil.copytree(Path(pretrained.__file__).parent / "hopper_small", folder / "hopper_small")
    for damaged, runtime in (("field.onnx", "onnx"), ("field.pt", "torch")):  # the file each runtime reads
        flip_byte(folder / "hopper_small" / damaged)
        out = one_line_error(predict("hopper", "alpha=40", "mu_s=0.3", "mu_r=0.1", f"runtime={runtime}",
                                     f"out={tmp_path / 'o'}", env={"NEURALDEM_MODELS": str(folder)}))
        assert f"{folder / 'hopper_small' / damaged} is damaged" in out and "neuraldem release" in out
        flip_byte(folder / "hopper_small" / damaged)


@pytest.mark.solver
def test_verify_runs_liggghts_beside_the_surrogate(tiny_pretrained: Path, tmp_path: Path):
    """A model built from the tiny checkpoint: verify=true runs LIGGGHTS at its scene (500 particles)."""
    proc = predict("hopper", "alpha=45", "mu_s=0.3", "mu_r=0.1", "verify=true", "time_stride=4",
                   "model=hopper_tiny_test", f"out={tmp_path}",
                   env={"NEURALDEM_PRETRAINED_DIR": str(tiny_pretrained)})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "| LIGGGHTS |" in proc.stdout
    answer = json.loads((tmp_path / "answer.json").read_text())
    ligg = answer["liggghts"]
    assert ligg["status"] == "ok" and ligg["seconds"] > 0 and 0 < ligg["metrics"]["drainage_t95"] < 5
    assert answer["gp"]["seconds"] < ligg["seconds"]
    again = predict("hopper", "alpha=45", "mu_s=0.3", "mu_r=0.1", "verify=true", "fields=false",
                    "model=hopper_tiny_test", f"out={tmp_path}", env={"NEURALDEM_PRETRAINED_DIR": str(tiny_pretrained)})
    assert again.returncode == 0 and "read back from" in again.stderr and "running LIGGGHTS" not in again.stderr
    assert json.loads((tmp_path / "answer.json").read_text())["liggghts"]["metrics"] == ligg["metrics"]


def test_the_old_flag_spelling_still_answers_and_prints_the_new_form(tmp_path: Path):
    proc = predict("hopper", "alpha=40", "mu_s=0.3", "mu_r=0.1", "--no-fields", "--out", str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    assert f"old spelling (kept for one release): neuraldem predict hopper alpha=40 mu_s=0.3 mu_r=0.1 fields=false " \
           f"out={tmp_path}" in proc.stderr
    assert "| drainage t95 [s] |" in proc.stdout
