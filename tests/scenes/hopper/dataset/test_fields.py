"""Occupancy / transport / residence from particles, on hand-checkable cases (hand-made particles)."""

from __future__ import annotations

import numpy as np

from neuraldem.scenes.hopper.dataset.fields import fields_at, trajectory_fields_at


def test_fields_at_particle_centres_and_far_away():
    initial = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    now = initial + [0.0, 0.0, -0.02]  # both moved down 2 cm
    exit_times = np.array([1.5, np.nan])  # the second never leaves
    pts = np.array([[0.0, 0.0, -0.02], [0.1, 0.0, -0.02], [0.0, 0.0, -0.0249], [0.5, 0.5, 0.5]])
    f = fields_at(pts, now, initial, exit_times, t=0.5, t_end=3.0, radius=0.006)
    assert f.occupied.tolist() == [True, True, True, False]
    np.testing.assert_allclose(f.transport[:3], initial[[0, 1, 0]])  # where the material came from
    assert np.isnan(f.transport[3]).all()
    np.testing.assert_allclose(f.residence[:3], [1.0, 2.5, 1.0])  # exit - t; never-left: t_end - t
    assert np.isnan(f.residence[3])


def test_exited_particles_leave_no_occupancy():
    pos = np.array([[[0.0, 0.0, 0.0]], [[np.nan, np.nan, np.nan]]])
    occ, transport, residence = trajectory_fields_at(pos[0], np.array([0.0, 0.1]), pos, np.array([0.05]), 0.006)
    assert occ.tolist() == [[True], [False]]
    assert residence[0, 0] == 0.05
