"""The fluidized-bed HDF5 file: round trip, next-step pairs, and a validating reader that names file and
field for every kind of damage."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from neuraldem.errors import DataError
from neuraldem.scenes.fluidized_bed.dataset.fields import solid_fraction
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile, write_fb_file
from neuraldem.scenes.fluidized_bed.solver.reader import BedTrajectory
from neuraldem.sim.foam_reader import BoxGrid

GRID = BoxGrid((0.0, 0.0, 0.0), (0.024, 0.006, 0.06), (6, 1, 15))


def make_trajectory(T: int = 5, N: int = 40, seed: int = 0) -> BedTrajectory:
    rng = np.random.default_rng(seed)
    pos = np.empty((T, N, 3))
    pos[0] = rng.uniform([0.001, 0.001, 0.001], [0.023, 0.005, 0.02], size=(N, 3))
    for t in range(1, T):
        pos[t] = np.clip(pos[t - 1] + rng.normal(0, 5e-4, size=(N, 3)), 0.001, [0.023, 0.005, 0.059])
    return BedTrajectory(
        times=np.round(np.arange(T) * 0.01, 9), t0=0.2, orig_proc=np.zeros(N, np.int64),
        orig_id=np.arange(N, dtype=np.int64), diameters=np.full(N, 0.002), density=2526.0, positions=pos,
        velocities=rng.normal(size=(T, N, 3)), lost_time=np.full(N, np.nan), grid=GRID,
        fluid_velocity=rng.normal(size=(T, 6, 1, 15, 3)), fluid_fraction=rng.uniform(0.4, 1, size=(T, 6, 1, 15)),
        pressure=rng.normal(size=(T, 6, 1, 15)), inflow=np.full(T, 2.9e-4), outflow=np.full(T, 2.9e-4))


@pytest.fixture
def stored(tmp_path: Path) -> tuple[Path, BedTrajectory]:
    traj = make_trajectory()
    path = tmp_path / "sim.h5"
    write_fb_file(path, "sim_x", traj, {"inlet_velocity": 1.5}, "test", 0.002, 0.001)
    return path, traj


def test_round_trip_and_pairs(stored):
    path, traj = stored
    with BedFile(path) as f:
        assert (f.n_snapshots, f.n_particles, f.grid) == (5, 40, GRID)
        assert f.inlet_velocity == 1.5 and f.t0 == 0.2 and f.density == 2526.0
        assert (f.kernel_sigma, f.mixing_sigma) == (0.002, 0.001) and f.dt == pytest.approx(0.01)
        np.testing.assert_allclose(f.positions(), traj.positions, atol=1e-8)
        np.testing.assert_allclose(f.fluid_velocity(), traj.fluid_velocity, rtol=1e-6)
        np.testing.assert_allclose(f.solid_fraction(2), solid_fraction(f.positions(2), f.diameters, GRID, 0.002),
                                   atol=1e-6)
        assert set(np.unique(f.labels)) == {0, 1}
        p = f.pair(2)
        np.testing.assert_allclose(p["position"] + p["target_displacement"], f.positions(3), atol=1e-7)
        np.testing.assert_allclose(p["displacement_in"], f.positions(2) - f.positions(1), atol=1e-7)
        np.testing.assert_allclose(p["target_solid_fraction"], f.solid_fraction(3))
        assert p["fluid_velocity"].shape == (6, 1, 15, 3) and p["mixing"].shape == (6, 1, 15)
        np.testing.assert_array_equal(f.pair(0)["displacement_in"], 0.0)
        with pytest.raises(DataError, match="no successor"):
            f.pair(4)
    assert not list(path.parent.glob("*.partial"))


def test_lost_particles_are_nan_after_their_lost_time(tmp_path: Path):
    traj = make_trajectory()
    traj.positions[3:, 7] = np.nan
    traj.velocities[3:, 7] = np.nan
    traj.lost_time[7] = 0.03
    write_fb_file(tmp_path / "lost.h5", "lost", traj, {}, "test", 0.002)
    with BedFile(tmp_path / "lost.h5") as f:
        assert np.isnan(f.positions(3)[7]).all() and np.isnan(f.displacement(2)[7]).all()
        total = f.solid_fraction().sum(axis=(1, 2, 3)) * GRID.cell_volume
        assert total[4] == pytest.approx(total[0] * 39 / 40, rel=1e-5)


def _tamper(src: Path, dst: Path, edit) -> Path:
    shutil.copy(src, dst)
    with h5py.File(dst, "r+") as f:
        edit(f)
    return dst


def _replace(name: str, value):
    def edit(f: h5py.File) -> None:
        del f[name]
        f[name] = value
    return edit


@pytest.mark.parametrize("edit,message", [
    (lambda f: f.attrs.__setitem__("schema_version", 99), "schema version 99"),
    (lambda f: f.attrs.__setitem__("kind", "hopper"), "kind 'hopper', expected 'fluidized_bed'"),
    (lambda f: f.__delitem__("snapshots/mixing"), "field /snapshots/mixing is missing"),
    (_replace("snapshots/time", np.array([0.0, 0.01, 0.01, 0.03, 0.04])), "/snapshots/time must start at 0"),
    (_replace("particles/orig_id", np.arange(40)[::-1]), "/particles/orig_id"),
    (_replace("particles/label", np.full(40, 2, np.int8)), "/particles/label must be 0 or 1"),
    (_replace("snapshots/solid_fraction", np.zeros((5, 6, 1, 15), np.float32)), "solid volume"),
    (_replace("snapshots/fluid_velocity", np.zeros((5, 6, 1, 14, 3), np.float32)),
     "/snapshots/fluid_velocity has shape"),
    (_replace("particles/lost_time", np.full(40, 0.02, np.float32)), "disagrees with /particles/lost_time"),
])
def test_damage_is_named(stored, tmp_path: Path, edit, message: str):
    path, _ = stored
    bad = _tamper(path, tmp_path / "bad.h5", edit)
    with pytest.raises(DataError, match=message) as err:
        BedFile(bad)
    assert str(bad) in str(err.value)


def test_displacement_must_match_positions(stored, tmp_path: Path):
    path, _ = stored

    def edit(f: h5py.File) -> None:
        f["snapshots/displacement"][1, 3, 0] += 1e-3

    with pytest.raises(DataError, match="/snapshots/displacement is not position"):
        BedFile(_tamper(path, tmp_path / "bad.h5", edit))


def test_not_hdf5_and_missing(tmp_path: Path):
    (tmp_path / "x.h5").write_bytes(b"not hdf5")
    with pytest.raises(DataError, match="not a readable HDF5 file"):
        BedFile(tmp_path / "x.h5")
    with pytest.raises(DataError, match="does not exist"):
        BedFile(tmp_path / "y.h5")


@pytest.mark.solver
def test_generated_files_validate(fb_tiny_dataset: Path):
    files = sorted((fb_tiny_dataset / "sims").glob("*.h5"))
    assert len(files) == 3
    for path in files:
        with BedFile(path) as f:
            assert f.n_snapshots == 21 and f.n_particles == 300 and f.grid.shape == (6, 1, 15)
            inflow, outflow = f.fluxes()
            np.testing.assert_allclose(outflow, inflow, rtol=1e-5)
            np.testing.assert_allclose(inflow, f.inlet_velocity * 0.024 * 0.006, rtol=1e-6)
