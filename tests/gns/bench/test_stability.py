import json

import pytest

from neuraldem.bench.__main__ import main
from neuraldem.errors import DataError
from neuraldem.gns.bench import stability as gns_stability
from neuraldem.gns.rollout import StabilityLimits
from tests.helpers import train_tiny_gns

FB_POINT_KEYS = {"inlet_velocity", "extrapolation", "initial_state", "steps_requested", "steps_done",
                 "steps_to_divergence", "divergence", "steps_to_drift_limit", "drift_pct_end", "max_abs_drift_pct",
                 "failed", "steps_to_failure", "failure", "steps_stable"}


@pytest.fixture(scope="module")
def fb_gns(fb_tiny_dataset, tmp_path_factory):
    return train_tiny_gns(fb_tiny_dataset, "fb_tiny", tmp_path_factory.mktemp("gns") / "fb.ckpt")


@pytest.mark.solver
def test_series_in_the_shape_of_fb_stability(fb_gns, fb_tiny_dataset):
    lenient = StabilityLimits(box_tolerance_d=1e6, overlap_fraction=0.0)
    res = gns_stability.run([fb_gns], ["gns"], velocities=[1.228531, 3.0], steps=4, dataset_dir=fb_tiny_dataset,
                            limits=lenient, progress=False)
    (s,) = res["series"]
    assert s["method"] == "gns" and s["trained_velocity_range"] == [1.228531, 1.228531]
    assert [p["extrapolation"] for p in s["points"]] == [False, True]
    for p in s["points"]:
        assert set(p) >= FB_POINT_KEYS
        assert p["steps_done"] == 4 or p["failed"]


@pytest.mark.solver
def test_command_writes_json_and_figure(fb_gns, fb_tiny_dataset, tmp_path):
    assert main(["gns_stability", f"ckpt=[{fb_gns}]", "velocities=[1.3]", "steps=2", f"dataset={fb_tiny_dataset}",
                 f"out={tmp_path}"]) == 0
    payload = json.loads((tmp_path / "gns_stability.json").read_text())
    assert payload["results"]["steps"] == 2 and (tmp_path / "gns_stability.png").is_file()


@pytest.mark.solver
def test_a_hopper_gns_is_refused(hopper_tiny_dataset, tmp_path):
    ckpt = train_tiny_gns(hopper_tiny_dataset, "hopper_tiny", tmp_path / "hopper.ckpt")
    with pytest.raises(DataError, match="experiment=gns_fb"):
        gns_stability.run([ckpt], steps=2, progress=False)
