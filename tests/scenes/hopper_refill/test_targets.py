"""Targets relative to a reference time and residence aggregation across resets.

All inputs here are synthetic unit-test inputs made by hand (a few particles with chosen positions,
insertion and exit times), so every expected number can be checked on paper; the real LIGGGHTS data goes
through the same functions in tests/scenes/hopper_refill/test_datagen.py."""

from __future__ import annotations

import numpy as np
import pytest

from neuraldem.errors import DataError
from neuraldem.scenes.hopper_refill.targets import (
    aggregated_residence,
    particle_query,
    particle_targets,
    reference_fields_at,
    reset_times,
    window_of,
)

# synthetic: 3 particles on snapshots every 0.5 s. Row 0 and 1 come from the fill (inserted at -0.3 s);
# row 0 sinks 1 cm per 0.5 s, row 1 rests and exits at 1.2 s; row 2 is refilled at 1.0 s and first seen at 1.5 s.
TIMES = np.array([0.0, 0.5, 1.0, 1.5, 2.0])
INSERT = np.array([-0.3, -0.3, 1.0])


def frame(k: int) -> tuple[np.ndarray, np.ndarray]:
    z0 = 0.10 - 0.01 * k
    rows, pos = [0], [[0.0, 0.0, z0]]
    if TIMES[k] < 1.2:
        rows.append(1)
        pos.append([0.05, 0.0, 0.05])
    if TIMES[k] >= 1.5:
        rows.append(2)
        pos.append([0.0, 0.0, 0.20 - 0.01 * (k - 3)])
    return np.array(rows), np.array(pos, dtype=np.float64)


def test_targets_relative_to_reference_by_hand():
    rows_t, pos_t = frame(4)  # t = 2.0: rows 0 and 2
    rows_r, pos_r = frame(1)  # t_ref = 0.5: rows 0 and 1
    tg = particle_targets(2.0, 0.5, rows_t, pos_t, rows_r, pos_r, INSERT)
    np.testing.assert_allclose(tg.transport[0], [0.0, 0.0, 0.09])  # where row 0 was at t_ref
    np.testing.assert_allclose(tg.displacement[0], [0.0, 0.0, -0.03])  # 0.06 - 0.09
    assert np.isnan(tg.transport[1]).all() and np.isnan(tg.displacement[1]).all()  # refilled after t_ref
    np.testing.assert_allclose(tg.residence, [1.5, 1.0])  # 2.0 - max(0.5, -0.3); 2.0 - max(0.5, 1.0)
    assert tg.new.tolist() == [False, True]


def test_reference_equal_to_t_gives_zero_residence_and_no_displacement():
    rows, pos = frame(2)
    tg = particle_targets(1.0, 1.0, rows, pos, rows, pos, INSERT)
    np.testing.assert_allclose(tg.residence, 0.0)
    np.testing.assert_allclose(tg.displacement, 0.0)
    assert not tg.new.any()


def test_fields_at_query_points_carry_the_nearest_particle():
    rows_t, pos_t = frame(4)
    rows_r, pos_r = frame(1)
    pts = np.array([[0.0, 0.0, 0.061], [0.0, 0.0, 0.19], [0.3, 0.3, 0.3]])
    f = reference_fields_at(pts, 2.0, 0.5, rows_t, pos_t, rows_r, pos_r, INSERT, radius=0.006)
    assert f.occupied.tolist() == [True, True, False]
    assert f.new.tolist() == [False, True, False]
    np.testing.assert_allclose(f.residence[:2], [1.5, 1.0])
    assert np.isnan(f.residence[2])


def test_reference_after_t_is_refused():
    rows, pos = frame(1)
    with pytest.raises(DataError, match=r"t_ref=1 s is after t=0.5 s.*choose t_ref <= t"):
        particle_targets(0.5, 1.0, rows, pos, rows, pos, INSERT)


def test_missing_insertion_times_are_refused():
    rows, pos = frame(4)
    with pytest.raises(DataError, match="insertion times are missing"):
        particle_targets(2.0, 0.5, rows, pos, *frame(1), np.array([-0.3, -0.3, np.nan]))


def test_resets_and_windows():
    np.testing.assert_allclose(reset_times(0.0, 2.0, 0.5), [0.0, 0.5, 1.0, 1.5, 2.0])
    r = np.array([0.0, 0.5, 1.5])
    assert [window_of(r, t) for t in (0.0, 0.49, 0.5, 1.4, 1.5, 2.0)] == [0, 0, 1, 1, 2, 2]
    with pytest.raises(DataError, match=r"window=0.0 must be > 0"):
        reset_times(0.0, 1.0, 0.0)


def test_aggregation_across_two_resets_by_hand():
    resets = np.array([0.0, 0.5, 1.5])  # two resets after the start
    query = particle_query(resets, TIMES, frame, INSERT, radius=0.006)
    rows, pos = frame(4)  # t = 2.0, query at the particle centres
    direct = 2.0 - INSERT[rows]  # 2.3 (fill material, since -0.3 s) and 1.0 (refilled at 1.0 s)
    at_least = aggregated_residence(query, resets, 2.0, pos)  # nothing known before r_0: residence since r_0
    np.testing.assert_allclose(at_least, [2.0, 1.0])
    known = aggregated_residence(query, resets, 2.0, pos, initial=lambda p: np.full(len(p), 0.3))
    np.testing.assert_allclose(known, direct)  # with the residence at r_0 known, exactly the direct value


def test_aggregation_equals_direct_residence_on_a_random_synthetic_flow():
    """Synthetic particles on a grid that drift down, exit at z < 0 and are refilled at the top; the
    aggregated residence over 4 resets equals t - insertion time for every particle inserted after r_0."""
    rng = np.random.default_rng(0)
    dt, n_steps, spacing = 0.1, 41, 0.02
    times = np.round(np.arange(n_steps) * dt, 9)
    # particle j sits at a fixed (x, y) column and falls with its own speed; it exists from its insertion
    # snapshot until it passes z = 0
    n = 300
    xy = np.stack(np.meshgrid(np.arange(15), np.arange(20)), -1).reshape(-1, 2)[:n] * spacing
    insert_k = rng.integers(-5, 30, n)
    speed = rng.uniform(0.01, 0.05, n)  # metres per second
    z_start = 0.5

    def fr(k: int) -> tuple[np.ndarray, np.ndarray]:
        z = z_start - speed * (k - np.maximum(insert_k, 0)) * dt - np.where(insert_k < 0, -insert_k * dt * speed, 0)
        alive = (k >= insert_k) & (z > 0)
        rows = np.flatnonzero(alive)
        return rows, np.column_stack([xy[rows], z[rows]])

    insert_times = insert_k * dt
    resets = np.array([0.0, 0.8, 1.6, 2.4, 3.2])
    query = particle_query(resets, times, fr, insert_times, radius=0.005)
    t = float(times[-1])
    rows, pos = fr(n_steps - 1)
    agg = aggregated_residence(query, resets, t, pos)
    after_r0 = insert_times[rows] >= 0
    assert after_r0.sum() > 50 and (t - insert_times[rows][after_r0]).max() > 2 * 0.8  # longer than 2 windows
    np.testing.assert_allclose(agg[after_r0], t - insert_times[rows][after_r0], atol=1e-9)
    np.testing.assert_allclose(agg[~after_r0], t - resets[0])  # fill material: at least since r_0
