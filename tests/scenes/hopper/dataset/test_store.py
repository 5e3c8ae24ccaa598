"""HDF5 storage of a hopper trajectory: round trip at the stated resolution, and every kind of damage
(NaN, wrong schema version, truncation, half-written file) rejected with the file and field named.

The trajectories here are small hand-made arrays (a unit test of the file format, not solver data)."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from neuraldem.data.schema import TMP_SUFFIX
from neuraldem.errors import DataError
from neuraldem.scenes.hopper.dataset.store import HopperFile, write_hopper_file
from neuraldem.scenes.hopper.solver import HopperGeometry, HopperTrajectory

RES = 1e-5


def make_traj(T: int = 4, N: int = 6, seed: int = 0) -> HopperTrajectory:
    rng = np.random.default_rng(seed)
    pos = np.repeat(rng.uniform(-0.1, 0.3, size=(1, N, 3)), T, axis=0)
    pos[:, :, 2] -= np.linspace(0, 0.05, T)[:, None]
    exit_times = np.full(N, np.nan)
    exit_times[:2] = [0.07, 0.12]  # particle 0 leaves after snapshot 1, particle 1 after snapshot 2
    times = np.arange(T) * 0.05
    for i, te in enumerate(exit_times[:2]):
        pos[times > te, i] = np.nan
    vel = np.where(np.isfinite(pos), -0.5, np.nan)
    geom = HopperGeometry(radius=0.1, outlet_radius=0.04, cone_height=0.0, wall_height=0.4, sink_z=-0.05)
    return HopperTrajectory(ids=np.arange(1, N + 1) * 3, times=times, positions=pos, velocities=vel,
                            exit_times=exit_times, n_inserted=N, geometry=geom)


@pytest.fixture
def stored(tmp_path: Path) -> tuple[Path, HopperTrajectory]:
    traj = make_traj()
    path = tmp_path / "sim_0000.h5"
    write_hopper_file(path, "sim_0000", traj, {"alpha": 30.0, "mu_s": 0.5, "mu_r": 0.1}, "test", RES)
    return path, traj


def test_round_trip_within_resolution(stored):
    path, traj = stored
    with HopperFile(path) as f:
        back = f.load()
        assert f.params == {"alpha": 30.0, "mu_s": 0.5, "mu_r": 0.1}
    assert np.array_equal(np.isnan(back.positions), np.isnan(traj.positions))
    err = np.nanmax(np.abs(back.positions - traj.positions))
    assert err <= RES / 2 + 1e-12
    np.testing.assert_array_equal(back.ids, traj.ids)
    np.testing.assert_allclose(back.exit_times, traj.exit_times, rtol=1e-6)
    np.testing.assert_allclose(back.velocities, traj.velocities)
    assert back.geometry == traj.geometry


def test_no_partial_file_left_behind(stored):
    path, _ = stored
    assert not list(path.parent.glob(f"*{TMP_SUFFIX}"))


def test_failed_write_leaves_nothing(tmp_path: Path):
    traj = make_traj()
    traj.positions[1, 3] = [10.0, 0.0, 0.0]  # 10 m: does not fit int16 at 1e-5 m
    with pytest.raises(DataError, match="position_resolution"):
        write_hopper_file(tmp_path / "x.h5", "x", traj, {}, "test", RES)
    assert list(tmp_path.iterdir()) == []


def _corrupt(path: Path, fn) -> None:
    with h5py.File(path, "r+") as f:
        fn(f)


def test_nan_velocity_of_present_particle(stored):
    path, _ = stored
    _corrupt(path, lambda f: f["snapshots/velocity"].__setitem__((0, 3, 0), np.nan))
    with pytest.raises(DataError, match=r"sim_0000\.h5: /snapshots/velocity has NaN"):
        HopperFile(path)


def test_other_schema_version(stored):
    path, _ = stored
    _corrupt(path, lambda f: f.attrs.__setitem__("schema_version", 99))
    with pytest.raises(DataError, match="schema version 99.*regenerate"):
        HopperFile(path)


def test_missing_field_and_bad_shapes(stored):
    path, _ = stored
    _corrupt(path, lambda f: f.__delitem__("particles/exit_time"))
    with pytest.raises(DataError, match="/particles/exit_time is missing"):
        HopperFile(path)


def test_truncated_file(stored):
    path, _ = stored
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match="not a readable HDF5 file"):
        HopperFile(path)


def test_reappearing_particle(stored):
    path, _ = stored
    _corrupt(path, lambda f: f["snapshots/position"].__setitem__((3, 0), [0, 0, 0]))
    with pytest.raises(DataError, match="reappears"):
        HopperFile(path)
