"""The export formats on synthetic arrays: exit rules, statistics, and writing + reading back both layouts as the
public readers expect them (gns: `np.load(allow_pickle=True)` items of (positions, types[, material]);
LagrangeBench: groups 00000.. with `position` and `particle_type`, padding type -1)."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from neuraldem.errors import DataError
from neuraldem.export.formats import (
    FORMAT_VERSION,
    METADATA,
    PAD,
    Moments,
    SplitWriter,
    StepStatistics,
    Trajectory,
    apply_exit_rule,
    exit_steps,
    read_export,
    read_metadata,
    tool_metadata,
)


def leaving(T: int = 8, N: int = 5, seed: int = 0) -> np.ndarray:
    """Positions (T, N, 3) of N particles, particle k gone from snapshot exits[k] on (NaN)."""
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.normal(0, 0.01, (T, N, 3)), axis=0) + 0.5
    for k, e in enumerate([T, 3, 5, T, 7][:N]):
        x[e:, k] = np.nan
    return x


def test_exit_rules():
    x = leaving()
    assert exit_steps(x).tolist() == [8, 3, 5, 8, 7]
    held, steps = apply_exit_rule(x, "hold")
    assert held.shape == x.shape and np.isfinite(held).all() and steps.tolist() == [8, 3, 5, 8, 7]
    np.testing.assert_array_equal(held[:3], x[:3])
    np.testing.assert_array_equal(held[3:, 1], np.repeat(x[2:3, 1], 5, axis=0))  # at its last position
    cut, steps = apply_exit_rule(x, "truncate")
    np.testing.assert_array_equal(cut, x[:3])
    assert steps.tolist() == [3] * 5  # nobody leaves within the kept snapshots


def test_moments_merge_like_one_pass():
    rng = np.random.default_rng(1)
    chunks = [rng.normal(3.0, 2.0, (n, 3)) for n in (1, 40, 7, 300)]
    m = Moments()
    for c in chunks:
        m.add(c)
    m.add(np.zeros((0, 3)))
    every = np.concatenate(chunks)
    np.testing.assert_allclose(m.mean, every.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(m.std(), every.std(axis=0), rtol=1e-12)


def test_statistics_leave_out_the_steps_of_held_particles():
    x = leaving()
    held, steps = apply_exit_rule(x, "hold")
    traj = Trajectory("a", held.astype(np.float32), np.zeros(5, np.int64), steps)
    s = StepStatistics()
    s.add(traj)
    out = s.to_dict()
    x32 = held.astype(np.float32).astype(np.float64)
    x32[np.isnan(x)] = np.nan  # the held steps are not data
    v = (x32[1:] - x32[:-1]).reshape(-1, 3)
    a = (x32[2:] - 2 * x32[1:-1] + x32[:-2]).reshape(-1, 3)
    v, a = v[np.isfinite(v).all(1)], a[np.isfinite(a).all(1)]
    np.testing.assert_allclose(out["vel_mean"], v.mean(0), rtol=1e-10)
    np.testing.assert_allclose(out["acc_std"], a.std(0), rtol=1e-10)
    with pytest.raises(DataError, match="no particle with 3 consecutive snapshots"):
        StepStatistics().to_dict()


def write_export(folder: Path, fmt: str, parts: dict[str, list[Trajectory]], n_pad: int | None = None,
                 material: str | None = None) -> None:
    """A minimal export folder: split files + metadata with the neuraldem section the reader needs."""
    folder.mkdir()
    listed = {}
    for part, trajs in parts.items():
        listed[part] = [{"sim_id": t.sim_id, "conditioning": t.conditioning} for t in trajs]
        if trajs:
            w = SplitWriter(folder, fmt, part, material, n_pad, write_exits=True)
            for t in trajs:
                w.add(t)
            w.close()
    lengths = {p: [t.n_snapshots for t in ts] for p, ts in parts.items()}
    stats = StepStatistics()
    for t in parts["train"]:
        stats.add(t)
    meta = tool_metadata(fmt, dim=3, dt=0.01, bounds=np.array([[0, 1.0]] * 3), radius=0.02, diameter=0.01,
                         case="TEST", solver="none", lengths=lengths, n_particles_max=n_pad or 5,
                         stats=stats.to_dict(), material_property=material is not None)
    meta["neuraldem"] = {"format": fmt, "format_version": FORMAT_VERSION, "kind": "hopper", "trajectories": listed}
    (folder / METADATA).write_text(json.dumps(meta))


def synthetic_parts(counts=(5, 5, 4)) -> dict[str, list[Trajectory]]:
    out = {}
    for part, n, seed in zip(("train", "val", "test"), counts, (0, 1, 2), strict=True):
        held, steps = apply_exit_rule(leaving(N=n, seed=seed), "hold")
        out[part] = [Trajectory(f"sim_{seed}", held.astype(np.float32), np.zeros(n, np.int64), steps,
                                {"inlet_velocity": 1.0 + seed})]
    return out


@pytest.mark.parametrize("fmt", ["gns", "lagrangebench"])
def test_both_layouts_round_trip(fmt: str, tmp_path: Path):
    parts = synthetic_parts()
    pad = 5 if fmt == "lagrangebench" else None
    write_export(tmp_path / "x", fmt, parts, n_pad=pad, material="inlet_velocity" if fmt == "gns" else None)
    back = read_export(tmp_path / "x")
    for part, trajs in parts.items():
        (got,) = back.parts[part]
        want = trajs[0]
        np.testing.assert_array_equal(got.positions, want.positions)  # float32, bit for bit
        np.testing.assert_array_equal(got.exit_step, want.exit_step)
        np.testing.assert_array_equal(got.particle_type, want.particle_type)
        np.testing.assert_array_equal(got.physical(), want.physical())  # NaN where gone, as the dataset has it
        assert got.conditioning == want.conditioning and got.sim_id == want.sim_id


def test_the_gns_layout_is_what_the_gns_package_reads(tmp_path: Path):
    parts = synthetic_parts()
    write_export(tmp_path / "x", "gns", parts, material="inlet_velocity")
    with np.load(tmp_path / "x" / "train.npz", allow_pickle=True) as z:  # as gns/data_loader.py load_npz_data
        data = [item for _, item in z.items()]
    positions, types, material = data[0]
    assert positions.dtype == np.float32 and positions.shape == (8, 5, 3) and types.shape == (5,)
    assert np.full(positions.shape[1], types, dtype=int).shape == (5,) and material == 1.0
    meta = json.loads((tmp_path / "x" / METADATA).read_text())
    assert meta["sequence_length"] == 7 and meta["nnode_in"] == 38 and meta["nedge_in"] == 4
    for key in ("bounds", "default_connectivity_radius", "dim", "dt", "vel_mean", "vel_std", "acc_mean", "acc_std"):
        assert key in meta


def test_the_lagrangebench_layout_pads_unequal_particle_counts(tmp_path: Path):
    parts = synthetic_parts(counts=(5, 5, 4))
    write_export(tmp_path / "x", "lagrangebench", parts, n_pad=5)
    with h5py.File(tmp_path / "x" / "test.h5", "r") as f:  # as lagrangebench/data/data.py H5Dataset
        assert list(f.keys()) == ["00000"] and f["00000/position"].shape == (8, 5, 3)
        assert f["00000/particle_type"][()].tolist() == [0, 0, 0, 0, PAD]
    meta = json.loads((tmp_path / "x" / METADATA).read_text())
    assert meta["sequence_length_train"] == 7 and meta["num_trajs_test"] == 1
    assert meta["periodic_boundary_conditions"] == [False] * 3 and meta["write_every"] == 1
    assert read_export(tmp_path / "x").parts["test"][0].positions.shape == (8, 4, 3)  # padding dropped


def test_damaged_exports_are_one_line(tmp_path: Path):
    with pytest.raises(DataError, match="no export at"):
        read_metadata(tmp_path / "nothing")
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / METADATA).write_text(json.dumps({"bounds": [[0, 1]], "dim": 1}))
    with pytest.raises(DataError, match="not written by `neuraldem export`"):
        read_metadata(tmp_path / "foreign")
    write_export(tmp_path / "x", "gns", synthetic_parts())
    (tmp_path / "x" / "valid.npz").write_bytes(b"PK\x03\x04" + bytes(20))
    with pytest.raises(DataError, match="valid.npz is unreadable"):
        read_export(tmp_path / "x")
    (tmp_path / "x" / "valid.npz").unlink()
    with pytest.raises(DataError, match="valid.npz is missing"):
        read_export(tmp_path / "x")
