"""`neuraldem bench whatif_fb` on the tiny shipped bed model: answer times written with their command, and a
`predict fb` folder without a DPMFoam check refused by name."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.errors import DataError


def test_times_are_written_and_an_unverified_folder_is_refused(fb_tiny_pretrained: Path, tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch):
    from neuraldem.scenes.fluidized_bed.bench.predict_timing import main, verified_rows
    from neuraldem.scenes.fluidized_bed.predict import predict_fb

    monkeypatch.setenv("NEURALDEM_PRETRAINED_DIR", str(fb_tiny_pretrained))
    out = tmp_path / "whatif_fb.json"
    assert main(["model=fb_tiny_test", "repeats=1", f"out={out}"]) == 0
    result = json.loads(out.read_text())
    times = result["results"]["answer_times"]
    assert times["rollout_steps"] == 19 and times["field_in_process"]["median_wall_s"] > 0
    numbers, whole = (times[k]["median_wall_s"] for k in ("predict_command_numbers", "predict_command_with_pictures"))
    assert 0 < numbers < whole  # the numbers come out before the pictures are drawn
    assert "neuraldem bench whatif_fb model=fb_tiny_test" in out.with_suffix(".md").read_text()
    folder = tmp_path / "unverified"
    predict_fb({"inlet_velocity": 1.5}, "fb_tiny_test", folder, fields=False, verify=False)
    with pytest.raises(DataError, match="has no finished DPMFoam check"):
        verified_rows([folder])
