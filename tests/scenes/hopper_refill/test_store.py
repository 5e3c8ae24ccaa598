"""HDF5 storage of a refill trajectory (a changing particle set): round trip, and damaged or incomplete
files refused with the file, the field and the fix named.

The trajectories here are small hand-made arrays (a unit test of the file format, not solver data)."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from neuraldem.errors import DataError
from neuraldem.scenes.hopper.solver import HopperGeometry
from neuraldem.scenes.hopper_refill.solver import RefillTrajectory
from neuraldem.scenes.hopper_refill.store import RefillFile, write_refill_file

RES = 1e-5
GEOM = HopperGeometry(radius=0.1, outlet_radius=0.04, cone_height=0.0, wall_height=0.4, sink_z=-0.05)


def make_traj() -> RefillTrajectory:
    """Synthetic: ids 1, 2 from the fill (inserted at -0.3 s); id 1 exits at 0.07 s; id 7 is refilled at
    0.06 s and seen from the snapshot at 0.1 s on. Snapshots every 0.05 s."""
    times = np.array([0.0, 0.05, 0.1, 0.15])
    frames = [([0, 1], [[0.0, 0.0, 0.05], [0.05, 0.0, 0.1]]),
              ([0, 1], [[0.0, 0.0, 0.02], [0.05, 0.0, 0.09]]),
              ([1, 2], [[0.05, 0.0, 0.08], [0.0, 0.0, 0.35]]),
              ([1, 2], [[0.05, 0.0, 0.07], [0.0, 0.0, 0.30]])]
    index = np.concatenate([np.array(r) for r, _ in frames])
    pos = np.concatenate([np.array(p, dtype=np.float64) for _, p in frames])
    return RefillTrajectory(ids=np.array([1, 2, 7]), insert_times=np.array([-0.3, -0.3, 0.06]),
                            exit_times=np.array([0.07, np.nan, np.nan]), times=times,
                            offsets=np.array([0, 2, 4, 6, 8]), index=index, positions=pos,
                            velocities=np.full_like(pos, -0.5), n_initial=2, geometry=GEOM)


@pytest.fixture
def stored(tmp_path: Path) -> Path:
    path = tmp_path / "sim_0000.h5"
    write_refill_file(path, "sim_0000", make_traj(), {"alpha": 30.0, "mu_s": 0.5, "mu_r": 0.1}, "test", RES,
                      refill={"interval": 0.05})
    return path


def test_round_trip_within_resolution(stored: Path):
    ref = make_traj()
    with RefillFile(stored) as f:
        tr = f.load()
        rows, pos = f.frame(2)
        assert f.refill == {"interval": 0.05}
    np.testing.assert_array_equal(tr.ids, ref.ids)
    np.testing.assert_array_equal(tr.insert_times, ref.insert_times)
    np.testing.assert_allclose(tr.exit_times, ref.exit_times, rtol=1e-6)
    np.testing.assert_array_equal(tr.offsets, ref.offsets)
    np.testing.assert_allclose(tr.positions, ref.positions, atol=RES / 2 + 1e-12)
    assert rows.tolist() == [1, 2] and tr.n_initial == 2
    np.testing.assert_allclose(pos, [[0.05, 0.0, 0.08], [0.0, 0.0, 0.35]], atol=RES)


def _edit(path: Path, fn) -> None:
    with h5py.File(path, "r+") as f:
        fn(f)


def test_missing_insertion_times_name_field_and_fix(stored: Path):
    _edit(stored, lambda f: f.__delitem__("particles/insert_time"))
    with pytest.raises(DataError, match=r"sim_0000.h5: field /particles/insert_time is missing.*regenerate"):
        RefillFile(stored)


def test_nan_insertion_time(stored: Path):
    def nan(f: h5py.File) -> None:
        f["particles/insert_time"][2] = np.nan

    _edit(stored, nan)
    with pytest.raises(DataError, match=r"/particles/insert_time has 1 NaN/inf"):
        RefillFile(stored)


def test_reused_id_is_refused(tmp_path: Path):
    tr = make_traj()
    tr.index = np.array([0, 1, 0, 1, 1, 2, 0, 1])  # id 1 gone at 0.1 s and back at 0.15 s
    tr.index[-2:] = [0, 1]
    write_refill_file(tmp_path / "bad.h5", "bad", tr, {}, "test", RES)
    with pytest.raises(DataError, match="leave and reappear.*used twice"):
        RefillFile(tmp_path / "bad.h5")


def test_present_before_insertion_is_refused(tmp_path: Path):
    tr = make_traj()
    tr.insert_times = np.array([-0.3, -0.3, 0.12])  # id 7 seen at 0.1 s, inserted at 0.12 s?
    write_refill_file(tmp_path / "bad.h5", "bad", tr, {}, "test", RES)
    with pytest.raises(DataError, match="present before their insertion time"):
        RefillFile(tmp_path / "bad.h5")


def test_bad_offsets_and_shapes(stored: Path):
    def offsets(f: h5py.File) -> None:
        f["snapshots/offsets"][-1] = 7

    _edit(stored, offsets)
    with pytest.raises(DataError, match=r"/snapshots/offsets must have 5 non-decreasing entries"):
        RefillFile(stored)


def test_other_kind_and_schema(stored: Path):
    _edit(stored, lambda f: f.attrs.__setitem__("schema_version", 99))
    with pytest.raises(DataError, match="schema version 99"):
        RefillFile(stored)
