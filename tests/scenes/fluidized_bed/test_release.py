"""Releasing a bed model: its rollout options written into field.pt before anything is scored, and a dataset of
held-out runs scored (and its read recorded there) instead of the checkpoint's own test runs; a held-out dataset of
another scene, or one that does not exist, is refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.errors import DataError
from neuraldem.scenes.fluidized_bed.release import build_fluidized_bed
from tests.helpers import copy_dataset, run_module

OPTIONS = {"rollout_noise": 2.0, "mirror_alternate": True}


def held_out(fb_tiny_dataset: Path, folder: Path, scene_change: dict | None = None) -> Path:
    """fb_tiny's runs as a dataset of held-out runs (all of them in its test part)."""
    data = copy_dataset(fb_tiny_dataset, folder)
    m = json.loads((data / "manifest.json").read_text())
    m["name"] = folder.name
    ids = [s["sim_id"] for s in m["simulations"] if s["status"] == "ok"]
    m["splits"]["velocity"] = {"train": [], "val": [], "test": ids}
    if scene_change:
        m["scene"]["fluidized_bed"].update(scene_change)
    (data / "manifest.json").write_text(json.dumps(m))
    return data


def selection_json(path: Path, ckpt: Path) -> Path:
    """What `report fb-select` writes, having chosen `ckpt` (step 20 of two)."""
    rows = [{"step": 10, "sum": 0.3}, {"step": 20, "sum": 0.2}]
    path.write_text(json.dumps({"from_step": 10, "rollout_noise": 2.0, "mirror_alternate": True, "seeds": [0, 1],
                                "long_val": {"fb_tiny_longval": "x"}, "rows": rows,
                                "selected": {"step": 20, "copied_to": str(ckpt)}}))
    return path


def scan_json(path: Path, ckpt: Path) -> Path:
    """What `bench fb_stability` writes for `ckpt`: three velocities, the highest one's bed too high."""
    def point(v: float, dev: float) -> dict:
        return {"inlet_velocity": v, "bed_checked": True, "bed_deviation_pct": dev, "ok": abs(dev) <= 10,
                "bed_failure": "" if abs(dev) <= 10 else f"bed {dev:+.1f} % from CFD-DEM's"}
    series = {"checkpoint": str(ckpt), "points": [point(1.3, -1.0), point(1.6, 2.0), point(1.9, 12.5)]}
    path.write_text(json.dumps({"results": {"steps": 500, "rollout_noise": 2.0, "advection_correction": 0.75,
                                            "mirror_alternate": True, "drift_limit_pct": 5.0, "bed_limit_pct": 10.0,
                                            "series": [series]}}))
    return path


def test_options_and_held_out_runs_go_into_the_release(fb_tiny_pretrained: Path, fb_tiny_dataset: Path,
                                                       tmp_path: Path):
    from neuraldem.eval.checkpoints import read_checkpoint
    from neuraldem.scenes.fluidized_bed.surrogate.rollout import ModelStepper

    held = held_out(fb_tiny_dataset, tmp_path / "fb_tiny_heldout")
    ckpt = fb_tiny_pretrained / "fb_tiny_test" / "field.pt"
    folder = build_fluidized_bed(ckpt, "fb_rel", tmp_path / "out", fb_tiny_dataset, lacey_time=0.1, progress=False,
                                 rollout_options=OPTIONS, test_dataset=held,
                                 selection=selection_json(tmp_path / "sel.json", ckpt),
                                 stability_scan=scan_json(tmp_path / "scan.json", ckpt))
    meta = json.loads((folder / "meta.json").read_text())
    assert "step 20 among 2" in meta["chosen"] and "sum of the pooled errors (time mean + std field + Lacey) 0.200" \
        in meta["chosen"] and "fb_tiny_longval" in meta["chosen"]
    assert meta["stability"].startswith("3 inlet velocities 1.3 .. 1.9 m/s, 500 steps each") and \
        "1 failed" in meta["stability"] and "-1.0 to +12.5 %" in meta["stability"]
    assert meta["weak_regions"] == [{"parameters": {"inlet_velocity": 1.9}, "note": "bed +12.5 % from CFD-DEM's"}]
    card = (folder / "MODEL_CARD.md").read_text()
    assert "of `fb_tiny_heldout` (not the training dataset's own test part)" in card
    assert "- {'inlet_velocity': 1.9}: bed +12.5 % from CFD-DEM's" in card and meta["chosen"] in card
    assert meta["rollout_options"] == {**OPTIONS, "advection_correction": 0.75}  # the third as trained
    stepper = ModelStepper(read_checkpoint(folder / "field.pt").module("fluidized_bed", "cpu", "test"), 1.5)
    assert stepper.stability.mirror_alternate is True and stepper.stability.rollout_noise == 2.0
    rows = meta["test_errors"]["runs"]
    assert [r["sim_id"] for r in rows] == ["sim_0000", "sim_0001", "sim_0002"]
    assert {r["dataset"] for r in rows} == {"fb_tiny_heldout"}
    assert meta["training_data"]["test_dataset"]["run_ids"] == ["sim_0000", "sim_0001", "sim_0002"]
    assert meta["training_data"]["dataset"] == "fb_tiny"
    assert "seed floor" in meta["test_errors"]  # two packings of one velocity among the held-out runs
    reads = json.loads((held / "test_reads.json").read_text())
    assert [r["model"] for r in reads] == ["fb_rel"]
    assert not (fb_tiny_dataset / "test_reads.json").exists() or all(
        r["model"] != "fb_rel" for r in json.loads((fb_tiny_dataset / "test_reads.json").read_text()))
    assert meta["rebuild"][-1].endswith("name=fb_rel lacey_time=0.1 test_dataset=fb_tiny_heldout "
                                        "rollout.mirror_alternate=true rollout.rollout_noise=2")


def test_a_selection_of_another_checkpoint_is_refused_before_anything_is_read(
        fb_tiny_pretrained: Path, fb_tiny_dataset: Path, tmp_path: Path):
    held = held_out(fb_tiny_dataset, tmp_path / "fb_tiny_heldout")
    ckpt = fb_tiny_pretrained / "fb_tiny_test" / "field.pt"
    other = selection_json(tmp_path / "sel.json", tmp_path / "other.ckpt")
    with pytest.raises(DataError, match="fb-select chose .*other.ckpt, not ckpt="):
        build_fluidized_bed(ckpt, "fb_rel", tmp_path / "out", fb_tiny_dataset, lacey_time=0.1, progress=False,
                            test_dataset=held, selection=other)
    assert not (tmp_path / "out").exists() and not (held / "test_reads.json").exists()


def test_a_held_out_dataset_of_another_scene_is_refused(fb_tiny_pretrained: Path, fb_tiny_dataset: Path,
                                                        tmp_path: Path):
    held = held_out(fb_tiny_dataset, tmp_path / "other", scene_change={"width": 0.5})
    ckpt = fb_tiny_pretrained / "fb_tiny_test" / "field.pt"
    with pytest.raises(DataError, match="its scene differs from the training dataset fb_tiny's"):
        build_fluidized_bed(ckpt, "fb_rel", tmp_path / "out", fb_tiny_dataset, lacey_time=0.1, progress=False,
                            test_dataset=held)
    assert not (tmp_path / "out").exists() and not (held / "test_reads.json").exists()


def test_a_lacey_time_past_the_runs_is_refused_before_the_test_runs_are_read(
        fb_tiny_pretrained: Path, fb_tiny_dataset: Path, tmp_path: Path):
    held = held_out(fb_tiny_dataset, tmp_path / "fb_tiny_heldout")
    ckpt = fb_tiny_pretrained / "fb_tiny_test" / "field.pt"
    with pytest.raises(DataError, match="lacey_time=5 must lie in"):
        build_fluidized_bed(ckpt, "fb_rel", tmp_path / "out", fb_tiny_dataset, lacey_time=5.0, progress=False,
                            test_dataset=held)
    assert not (held / "test_reads.json").exists()


@pytest.mark.parametrize(("flags", "message"), [
    (["test_dataset=no_such_dataset"], "test_dataset=no_such_dataset is no dataset"),
    (["rollout.mirror_alternate=maybe"], "rollout.mirror_alternate=maybe is invalid"),
])
def test_bad_release_options_end_in_one_line(fb_tiny_pretrained: Path, tmp_path: Path, flags: list[str],
                                             message: str):
    ckpt = fb_tiny_pretrained / "fb_tiny_test" / "field.pt"
    proc = run_module("neuraldem.release", f"ckpt={ckpt}", "name=x", f"out={tmp_path}", *flags)
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert not (tmp_path / "x").exists()
