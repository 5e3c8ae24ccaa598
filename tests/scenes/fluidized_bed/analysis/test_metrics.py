"""Fluidized-bed metrics with known answers, the same metrics on real DPMFoam data (Lacey ~0 for the initial
left/right split, then rising), and the ground-truth report command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from neuraldem.scenes.fluidized_bed.analysis import metrics as fm
from neuraldem.scenes.fluidized_bed.dataset.fields import initial_labels, mixing_concentration, solid_fraction
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.sim.foam_reader import BoxGrid
from tests.helpers import run_module

GRID = BoxGrid((0.0, 0.0, 0.0), (0.048, 0.006, 0.12), (12, 1, 30))
VP = np.pi / 6 * 0.002**3


def test_lacey_index_known_values():
    n = np.full(8, 50.0)
    segregated = np.array([0, 0, 0, 0, 1, 1, 1, 1], float)
    assert fm.lacey_index(segregated, n) == pytest.approx(0.0)
    # every sample cell at exactly the mean: better than random, M = s0^2 / (s0^2 - sR^2)
    p = 0.5
    assert fm.lacey_index(np.full(8, p), n) == pytest.approx(1 / (1 - 1 / 50))
    # hand-computed: p = 0.5, s^2 = 0.01, s0^2 = 0.25, sR^2 = 0.005
    c = np.array([0.4, 0.6, 0.4, 0.6, 0.4, 0.6, 0.4, 0.6])
    assert fm.lacey_index(c, n) == pytest.approx((0.25 - 0.01) / (0.25 - 0.005))
    # cells below min_count do not count; count weighting
    assert fm.lacey_index(np.array([0, 1, 0.5]), np.array([50, 50, 2.0])) == pytest.approx(0.0)
    assert np.isnan(fm.lacey_index(np.ones(4), n[:4]))  # one group only: undefined
    assert np.isnan(fm.lacey_index(np.array([0.5]), np.array([1.0])))


def test_lacey_from_particles_segregated_zero_random_one():
    rng = np.random.default_rng(0)
    pos = rng.uniform([0, 0, 0], [0.048, 0.006, 0.03], size=(3000, 3))
    seg = initial_labels(pos, GRID)
    m_seg = fm.lacey_from_particles(pos[None], seg, GRID.lo, GRID.hi, GRID.shape, (2, 1, 2))[0]
    assert m_seg == pytest.approx(0.0, abs=1e-12)
    ms = [fm.lacey_from_particles(pos[None], rng.permutation(seg), GRID.lo, GRID.hi, GRID.shape, (2, 1, 2))[0]
          for _ in range(20)]
    assert np.mean(ms) == pytest.approx(1.0, abs=0.03) and np.std(ms) < 0.1


def test_lacey_from_fields_matches_particles_for_sharp_kernels():
    rng = np.random.default_rng(1)
    pos = rng.uniform([0, 0, 0], [0.048, 0.006, 0.03], size=(3000, 3))
    d = np.full(3000, 0.002)
    seg = initial_labels(pos, GRID)
    for labels, expected in ((seg, 0.0), (rng.permutation(seg), None)):
        a = solid_fraction(pos, d, GRID, 1e-5)
        c = mixing_concentration(pos, d, labels, GRID, 1e-5, prior=1e-9)
        mf = fm.lacey_from_fields(a[None], c[None], GRID.cell_volume, VP, (2, 1, 2))[0]
        mp = fm.lacey_from_particles(pos[None], labels, GRID.lo, GRID.hi, GRID.shape, (2, 1, 2))[0]
        assert mf == pytest.approx(mp, abs=1e-3)
        if expected is not None:
            assert mf == pytest.approx(expected, abs=1e-3)
    # with the default kernels the segregated interface is blurred: a small positive index
    a = solid_fraction(pos, d, GRID, 0.002)
    c = mixing_concentration(pos, d, seg, GRID, 0.001)
    assert 0.0 < fm.lacey_from_fields(a[None], c[None], GRID.cell_volume, VP, (2, 1, 2))[0] < 0.1


def test_bed_height_and_bubble_fraction_of_known_beds():
    z = GRID.edges(2)
    alpha = np.zeros((2, 12, 1, 30))
    alpha[:, :, :, :10] = 0.5  # a uniform bed 40 mm tall
    h = fm.bed_height(alpha, z, 0.95)
    np.testing.assert_allclose(h, 0.95 * 0.04)
    np.testing.assert_allclose(fm.bed_height(alpha, z, 0.5), 0.02)
    np.testing.assert_allclose(fm.bubble_fraction(alpha, z, h, 0.15), 0.0)
    alpha[1, 4:8, :, 2:6] = 0.02  # a void of 4 x 4 cells in the second snapshot
    h = fm.bed_height(alpha, z, 1.0)  # everything below: the full 40 mm
    np.testing.assert_allclose(h, 0.04)
    np.testing.assert_allclose(fm.bubble_fraction(alpha, z, h, 0.15), [0.0, 16 / 120])
    pos = np.zeros((1, 101, 3))
    pos[0, :, 2] = np.linspace(0, 0.1, 101)
    np.testing.assert_allclose(fm.bed_height_particles(pos, 0.95), 0.095)


def test_volume_statistics_and_blocks():
    alpha = np.random.default_rng(2).uniform(0, 0.6, size=(7, 12, 1, 30))
    vol = fm.total_solid_volume(alpha, GRID.cell_volume)
    np.testing.assert_allclose(vol, alpha.sum(axis=(1, 2, 3)) * GRID.cell_volume)
    assert fm.mass_conservation_error(np.array([2.0, 2.02, 1.99])) == pytest.approx(0.01)
    mean, std = fm.time_statistics(alpha)
    np.testing.assert_allclose(mean, alpha.mean(axis=0))
    np.testing.assert_allclose(std, alpha.std(axis=0))
    blocks = fm.block_sums(alpha, (2, 1, 4))
    assert blocks.shape == (7, 6, 1, 8)  # 30 / 4: the last block is partial
    np.testing.assert_allclose(blocks.sum(axis=(1, 2, 3)), alpha.sum(axis=(1, 2, 3)))
    np.testing.assert_allclose(fm.fluid_speed(np.array([[3.0, 0.0, 4.0]])), [5.0])
    assert fm.first_crossing(np.arange(4.0), np.array([0.1, 0.4, 0.6, 0.7]), 0.5) == 2.0


@pytest.mark.solver
def test_lacey_starts_near_zero_and_rises_on_real_data(fb_tiny_dataset: Path):
    """Requirement, on the real solver: the initial left/right split scores ~0, then mixing rises."""
    for path in sorted((fb_tiny_dataset / "sims").glob("*.h5")):
        with BedFile(path) as f:
            pos, alpha, mix = f.positions(), f.solid_fraction(), f.mixing()
            lp = fm.lacey_from_particles(pos, f.labels, f.grid.lo, f.grid.hi, f.grid.shape, (1, 1, 2))
            lf = fm.lacey_from_fields(alpha, mix, f.grid.cell_volume, float(f.particle_volumes.mean()), (1, 1, 2))
        assert abs(lp[0]) < 1e-9  # the split itself: exactly segregated sample cells
        assert 0 < lf[0] < 0.2  # the kernel blurs the interface by ~1 mm
        assert lp[-5:].mean() > lp[0] + 0.08 and lf[-5:].mean() > lf[0] + 0.03, (lp, lf)


@pytest.mark.solver
def test_ground_truth_metrics_in_the_manifest(fb_tiny_dataset: Path):
    m = json.loads((fb_tiny_dataset / "manifest.json").read_text())
    low, high = m["simulations"][0], m["simulations"][-1]
    assert low["params"]["inlet_velocity"] < high["params"]["inlet_velocity"]
    for r in (low, high):
        assert r["metrics"]["solid_volume_error"] < 1e-5
        assert r["metrics"]["flux_imbalance_max"] < 1e-5
    assert high["metrics"]["bed_height_mean"] > low["metrics"]["bed_height_mean"]  # more air: taller bed
    assert m["parameters"]["metrics"]["lacey_block"] == [1, 1, 2]


@pytest.mark.solver
def test_report_command_writes_plots_and_json(fb_tiny_dataset: Path, tmp_path: Path):
    proc = run_module("neuraldem", "report", "fb-dataset", f"dataset={fb_tiny_dataset}", f"out={tmp_path / 'rep'}",
                      "note=test run")
    assert proc.returncode == 0, proc.stderr
    for name in ("curves.png", "time_averages.png", "solid_volume.png", "report.json"):
        assert (tmp_path / "rep" / name).stat().st_size > 0
    rep = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert rep["note"] == "test run" and len(rep["simulations"]) == 2
    v = [s["params"]["inlet_velocity"] for s in rep["simulations"]]
    assert v[0] < v[1]
    s = rep["simulations"][0]["series"]
    assert len(s["time"]) == len(s["lacey_field"]) == len(s["bed_height"]) == 21
    assert rep["cost"]["cpu_s_per_simulated_s"]["median"] > 0
    bad = run_module("neuraldem", "report", "fb-dataset", f"dataset={tmp_path / 'none'}", f"out={tmp_path / 'x'}")
    assert bad.returncode == 2 and "no fluidized-bed dataset" in bad.stderr and "Traceback" not in bad.stderr


def test_left_right_structure_known_answers():
    rng = np.random.default_rng(0)
    half = rng.random((6, 1, 10))
    symmetric = np.concatenate([half, half[::-1]])  # nx = 12, mirror image of itself
    assert fm.mirror_asymmetry(symmetric) == 0.0 and fm.lean(symmetric) == pytest.approx(0.0, abs=1e-15)
    one_column = np.zeros((4, 1, 3))
    one_column[0] = 1.0  # f - mirror(f) has two columns of the same norm
    assert fm.mirror_asymmetry(one_column) == pytest.approx(np.sqrt(2))
    assert fm.lean(one_column) == -1.0 and fm.lean(one_column[::-1]) == 1.0
    odd = np.zeros((3, 1, 2))
    odd[1] = 1.0  # the middle column of an odd grid is in neither half
    assert fm.lean(odd) == 0.0
    assert fm.wall_share(np.ones((12, 1, 5))) == pytest.approx(4 / 12)  # 2 columns at each wall of 12
    assert fm.wall_share(one_column) == 1.0 and fm.wall_share(odd) == 0.0  # nx // 6 = 0 -> 1 column
    assert fm.wall_share(np.ones((12, 1, 5)), columns=3) == pytest.approx(0.5)
    assert np.isnan(fm.lean(np.ones((1, 1, 5))))  # a single column has no sides
    with pytest.raises(ValueError, match="columns=0"):
        fm.wall_share(np.ones((12, 1, 5)), columns=0)
    truth = rng.random((12, 1, 10)) + 0.1
    # an error that is the same across x at each height is all profile; a mirror-antisymmetric one all lateral
    shift = fm.profile_lateral_error(truth + rng.random((1, 1, 10)), truth)
    assert shift["lateral"] == pytest.approx(0.0, abs=1e-14) and shift["profile"] == pytest.approx(shift["total"])
    anti = rng.random((6, 1, 10))
    tilt = fm.profile_lateral_error(truth + np.concatenate([anti, -anti[::-1]]), truth)
    assert tilt["profile"] == pytest.approx(0.0, abs=1e-14) and tilt["lateral"] == pytest.approx(tilt["total"])
    mixed = fm.profile_lateral_error(truth + rng.normal(size=truth.shape), truth)
    assert mixed["profile"] ** 2 + mixed["lateral"] ** 2 == pytest.approx(mixed["total"] ** 2)
    assert min(mixed["profile"], mixed["lateral"]) > 0
