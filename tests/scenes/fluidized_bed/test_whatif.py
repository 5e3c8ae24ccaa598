"""The bed's what-if answers on fields with known answers (synthetic fields, said so), and the shipped-state
file round trip on a real fb_tiny trajectory."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neuraldem.errors import DataError
from neuraldem.scenes.fluidized_bed.analysis.metric_settings import BedMetricSettings
from neuraldem.scenes.fluidized_bed.whatif import AnswerWindow, BedCurves, InitialStates, bed_answers, bed_curves
from neuraldem.sim.foam_reader import BoxGrid


def test_a_settled_unmixed_bed_has_its_known_height_no_bubbles_and_lacey_zero():
    grid = BoxGrid((0.0, 0.0, 0.0), (0.04, 0.01, 0.1), (4, 1, 10))  # 1-cm cells
    times = np.arange(1, 11) * 0.1
    sf = np.zeros((10, 4, 1, 10))
    sf[:, :, :, :4] = 0.6  # a uniform bed 4 cm deep (synthetic field)
    mix = np.zeros_like(sf)
    mix[:, 2:] = 1.0  # the right half is tagged, nothing mixed
    c = bed_curves(times, sf, mix, grid, particle_volume=4e-9,
                   settings=BedMetricSettings(lacey_block=(2, 1, 1), lacey_min_count=1.0))
    a = bed_answers(c, AnswerWindow(duration=1.0, lacey_time=0.5, dt=0.1))
    assert a["bed_height"] == pytest.approx(0.95 * 0.04)  # 95 % of the volume lies below 0.95 of the depth
    assert a["bubble_fraction"] == pytest.approx(0.0)
    assert a["lacey"] == pytest.approx(0.0, abs=1e-9)


def test_answers_are_read_inside_the_window_only():
    t = np.linspace(0.1, 2.0, 20)
    c = BedCurves(t, np.where(t <= 1.0, 0.02, 0.05), np.zeros_like(t), t / 2.0)
    a = bed_answers(c, AnswerWindow(duration=1.0, lacey_time=0.5, dt=0.1))
    assert a["bed_height"] == pytest.approx(0.02) and a["lacey"] == pytest.approx(0.25)
    short = bed_answers(BedCurves(t[:3], t[:3], t[:3], t[:3]), AnswerWindow(1.0, 0.5, 0.1))
    assert all(np.isnan(v) for v in short.values())  # a rollout that stopped before the Lacey time answers nothing


def test_shipped_states_round_trip_and_pick_the_nearest_velocity(fb_tiny_dataset: Path, tmp_path: Path):
    files = sorted((fb_tiny_dataset / "sims").glob("*.h5"))
    states = InitialStates.from_files(files)
    path = states.save_npz(tmp_path / "states.npz")
    back = InitialStates.load_npz(path)
    assert back.sim_ids == states.sim_ids and np.allclose(back.velocities, states.velocities)
    state, volume, name = back.nearest(float(states.velocities.max()) + 5.0)
    k = int(np.argmax(states.velocities))
    assert name.startswith(states.sim_ids[k]) and volume > 0
    assert np.isfinite(state.positions).all() and state.solids_flux is not None
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(DataError, match="bad.npz is damaged"):
        InitialStates.load_npz(tmp_path / "bad.npz")


def test_answers_stay_in_their_physical_range_and_a_fixed_bed_is_refused(tmp_path):
    """Below the minimum fluidization velocity (Wen & Yu, 1.07 m/s for fb_small) the bed does not bubble or mix:
    refused in one line with the velocity to ask at; near it, the GP's intervals end inside [0, 1] for the
    Lacey index and the bubble fraction (its stored range let them go negative)."""
    import json

    from tests.helpers import run_module

    fixed = run_module("neuraldem", "predict", "fluidized_bed", "inlet_velocity=0", "fields=false", f"out={tmp_path}")
    assert fixed.returncode == 2 and fixed.stderr.count("\n") == 1, fixed.stderr
    assert "below this bed's minimum fluidization velocity (1.07 m/s" in fixed.stderr
    assert "ask at inlet_velocity >= 1.07" in fixed.stderr
    low = run_module("neuraldem", "predict", "fluidized_bed", "inlet_velocity=1.08", "fields=false", "json=true",
                     f"out={tmp_path}")
    assert low.returncode == 0, low.stderr
    gp = json.loads(low.stdout)["gp"]
    for key in ("lacey", "bubble_fraction"):
        assert 0.0 <= gp["low"][key] <= gp["mean"][key] <= gp["high"][key] <= 1.0, (key, gp)
