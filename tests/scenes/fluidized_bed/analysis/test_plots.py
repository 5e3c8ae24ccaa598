"""Profiles across the bed: band averages with known answers, and the figure is written."""

from __future__ import annotations

import numpy as np

from neuraldem.scenes.fluidized_bed.analysis import plots


def test_lateral_profiles_average_over_y_and_the_cells_of_each_height_band(tmp_path):
    z = np.array([0.5, 1.5, 2.5, 3.5])
    field = np.zeros((3, 2, 4))
    field[:, :, 0] = 1.0  # the lowest layer
    field[2, 0, 1] = 4.0  # one cell of the second layer, one of two y cells
    prof = plots.lateral_profiles(field, z, [(0.0, 2.0), (2.0, 4.0), (9.0, 10.0)])
    assert np.allclose(prof[0], [0.5, 0.5, 1.5])  # (1 + 0) / 2, with (1 + 4 / 2) / 2 at x = 2
    assert np.allclose(prof[1], 0.0) and np.isnan(prof[2]).all()  # no cell centre in the last band
    stats = {name: {"solid_fraction_mean": field, "solid_fraction_std": 0.5 * field} for name in ("a", "b")}
    out = tmp_path / "p.png"
    plots.plot_lateral_profiles(stats, np.array([0.1, 0.2, 0.3]), z, 2.0, out, "t")
    assert out.stat().st_size > 1000
