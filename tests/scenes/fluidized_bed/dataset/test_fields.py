"""Kernel fields of the fluidized bed: exact volume, walls, mixing concentration; and on real DPMFoam data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neuraldem.scenes.fluidized_bed.dataset.fields import (
    axis_weights,
    displacements,
    group_b_share,
    initial_labels,
    mixing_concentration,
    particle_volumes,
    solid_fraction,
    solids_flux,
    trajectory_fields,
)
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.sim.foam_reader import BoxGrid

GRID = BoxGrid((0.0, 0.0, 0.0), (0.048, 0.006, 0.12), (12, 1, 30))


def test_axis_weights_integrate_to_one_with_walls():
    edges = np.linspace(0.0, 0.048, 13)
    x = np.array([0.0, 1e-4, 0.001, 0.024, 0.0479, 0.048])  # on and near both walls
    for sigma in (0.0005, 0.002, 0.02, 0.2):  # much wider than the box too
        w = axis_weights(x, edges, sigma)
        assert w.shape == (6, 12) and np.all(w >= 0)
        np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    w = axis_weights(np.array([0.024]), edges, 1e-5)  # a narrow kernel stays in its cell (the two at x = 24 mm)
    assert w[0, 5] + w[0, 6] == pytest.approx(1.0)
    mid = axis_weights(np.array([0.022]), edges, 0.002)[0]  # symmetric about the particle away from walls
    np.testing.assert_allclose(mid[4], mid[6], rtol=1e-9)


def test_one_cell_thick_axis_gets_everything():
    w = axis_weights(np.array([0.001, 0.003, 0.0059]), np.array([0.0, 0.006]), 0.002)
    np.testing.assert_allclose(w, 1.0)


@pytest.mark.parametrize("sigma", [0.0005, 0.002, 0.006])
def test_solid_fraction_integrates_to_the_particle_volume(sigma: float):
    rng = np.random.default_rng(0)
    pos = rng.uniform(GRID.lo, GRID.hi, size=(500, 3))
    pos[:10, 0] = 0.0  # some exactly on walls and in corners
    pos[10:20] = GRID.hi
    d = rng.uniform(0.0015, 0.0025, size=500)  # polydisperse
    alpha = solid_fraction(pos, d, GRID, sigma)
    assert alpha.shape == (12, 1, 30) and alpha.min() >= 0
    assert alpha.sum() * GRID.cell_volume == pytest.approx(particle_volumes(d).sum(), rel=1e-12)


def test_absent_particles_are_skipped_and_a_lone_particle_is_smooth():
    pos = np.array([[0.024, 0.003, 0.06], [np.nan, np.nan, np.nan]])
    d = np.array([0.002, 0.002])
    alpha = solid_fraction(pos, d, GRID, 0.002)
    assert alpha.sum() * GRID.cell_volume == pytest.approx(particle_volumes(d[:1]).sum())
    col = alpha[:, 0, 14] + alpha[:, 0, 15]
    assert col[5] == pytest.approx(col[6]) and col[5] > col[4] > col[3] > 0  # spread over neighbours


def test_mixing_concentration_definition():
    rng = np.random.default_rng(1)
    left = rng.uniform([0.001, 0.001, 0.001], [0.02, 0.005, 0.03], size=(300, 3))
    right = rng.uniform([0.028, 0.001, 0.001], [0.047, 0.005, 0.03], size=(200, 3))
    pos = np.concatenate([left, right])
    d = np.full(500, 0.002)
    labels = initial_labels(pos, GRID)
    assert labels.sum() == 200 and group_b_share(labels, d) == pytest.approx(0.4)
    c = mixing_concentration(pos, d, labels, GRID, 0.001)
    assert c.min() >= 0 and c.max() <= 1
    assert c[0, 0, 3] == pytest.approx(0.0, abs=5e-3) and c[11, 0, 3] == pytest.approx(1.0, abs=5e-3)  # prior: < 1 %
    assert c[5, 0, 29] == pytest.approx(0.4, abs=1e-6)  # empty space: the global share, no NaN
    alpha, conc = trajectory_fields(pos[None], d, labels, GRID, 0.002, 0.001)
    np.testing.assert_allclose(conc[0], c)
    np.testing.assert_allclose(alpha[0], solid_fraction(pos, d, GRID, 0.002))


def test_solids_flux_carries_each_particles_momentum():
    rng = np.random.default_rng(3)
    pos = rng.uniform(GRID.lo, GRID.hi, size=(50, 3))
    disp = rng.normal(0.0, 1e-3, size=(50, 3))
    diameters = np.full(50, 0.002)
    dt = 0.01
    flux = solids_flux(pos, disp, diameters, GRID, 0.002, dt)
    assert flux.shape == (*GRID.shape, 3)
    # the kernel weights of a particle sum to 1: the field integrates to sum_i V_i u_i exactly
    np.testing.assert_allclose(flux.sum(axis=(0, 1, 2)) * GRID.cell_volume,
                               (particle_volumes(diameters)[:, None] * disp / dt).sum(axis=0), rtol=1e-10)
    # one particle moving up: flux only along z, located where its solid fraction is
    one = solids_flux(pos[:1], np.array([[0.0, 0.0, 1e-3]]), diameters[:1], GRID, 0.002, dt)
    alpha = solid_fraction(pos[:1], diameters[:1], GRID, 0.002)
    np.testing.assert_allclose(one[..., 2], alpha * 0.1, rtol=1e-10, atol=1e-300)  # (denormals differ)
    assert not one[..., :2].any()
    gone = pos.copy()
    gone[0] = np.nan  # absent particles are skipped
    np.testing.assert_allclose(solids_flux(gone, disp, diameters, GRID, 0.002, dt),
                               solids_flux(pos[1:], disp[1:], diameters[1:], GRID, 0.002, dt), atol=1e-15)


def test_displacements_are_next_minus_now():
    pos = np.arange(2 * 3 * 3, dtype=float).reshape(2, 3, 3) ** 2
    np.testing.assert_array_equal(displacements(pos)[0], pos[1] - pos[0])


@pytest.mark.solver
def test_real_kernel_field_holds_the_particle_volume(fb_tiny_dataset: Path):
    """Requirement: solid volume of the kernel field = the particles' total volume within 1 %
    (it is exact up to float32 storage), at every snapshot of every trajectory."""
    for path in sorted((fb_tiny_dataset / "sims").glob("*.h5")):
        with BedFile(path) as f:
            alpha = f.solid_fraction()
            total = alpha.sum(axis=(1, 2, 3)) * f.grid.cell_volume
            particles = f.particle_volumes.sum()
            np.testing.assert_allclose(total, particles, rtol=1e-5)
            assert particles == pytest.approx(300 * np.pi / 6 * 0.002**3)
            # recomputed from the stored positions: the stored field, and smoother than DPMFoam's alpha
            again = solid_fraction(f.positions(5), f.diameters, f.grid, f.kernel_sigma)
            np.testing.assert_allclose(again, alpha[5], atol=1e-6)
            solver = 1 - f.grid_field("solver_fluid_fraction")
            assert alpha.max() < solver.max()
