"""Mirror augmentation in x: the mirrored sample is what the kernel fields of the mirrored particles are
(solid fraction, solids flux, mixing, checked against `fields` on the real fb_tiny DPMFoam dataset), half the
training samples are mirrored, and validation / test never are."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neuraldem.errors import ConfigError
from neuraldem.scenes.fluidized_bed.dataset.fields import mixing_concentration, solid_fraction, solids_flux
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.datamodule import BedDataModule
from neuraldem.scenes.fluidized_bed.surrogate.mirror import mirror_grid, mirror_points, mirror_vectors


def test_mirroring_twice_is_the_identity_and_flips_only_x():
    rng = np.random.default_rng(0)
    pos, vec, field = rng.random((5, 3)), rng.standard_normal((5, 3)), rng.standard_normal((4, 1, 3, 3))
    np.testing.assert_allclose(mirror_points(mirror_points(pos, 0.0, 2.0), 0.0, 2.0), pos, atol=1e-15)
    np.testing.assert_allclose(mirror_points(pos, 0.0, 2.0)[:, 0], 2.0 - pos[:, 0])
    np.testing.assert_array_equal(mirror_points(pos, 0.0, 2.0)[:, 1:], pos[:, 1:])
    np.testing.assert_array_equal(mirror_vectors(vec)[:, 1:], vec[:, 1:])
    np.testing.assert_array_equal(mirror_vectors(vec)[:, 0], -vec[:, 0])
    np.testing.assert_array_equal(mirror_grid(mirror_grid(field, True), True), field)
    np.testing.assert_array_equal(mirror_grid(field, False)[0], field[-1])
    np.testing.assert_array_equal(mirror_grid(field, True)[0, ..., 0], -field[-1, ..., 0])



@pytest.mark.solver
def test_a_mirrored_sample_is_the_fields_of_the_mirrored_particles(fb_tiny_dataset: Path):
    dm = BedDataModule(str(fb_tiny_dataset), "fb_tiny", batch_size=2, solids_flux=True, mirror=True)
    dm.setup("fit")
    ds, norm = dm.datasets["train"], dm.norm
    seed = next(s for s in range(100) if np.random.default_rng(s).random() < 0.5)  # a first draw that flips
    i = next(k for k in range(len(ds) // 2, len(ds)) if ds.items[k][1] > 0)  # a step with a displacement
    s, t = ds.items[i]
    item = ds.sample(i, np.random.default_rng(seed))  # every particle: no further draws
    with BedFile(dm.paths("train")[s]) as f:
        lo, hi = f.grid.lo[0], f.grid.hi[0]
        pos, disp = mirror_points(f.positions(t), lo, hi), mirror_vectors(f.displacement(t - 1))
        np.testing.assert_allclose(norm.positions_back(item["particle_pos"].double().numpy()), pos, atol=1e-7)
        np.testing.assert_allclose(norm.field_back("displacement", item["particle_features"].double().numpy()),
                                   disp, atol=1e-9)
        grid = np.moveaxis(item["grid"].double().numpy(), 0, -1)  # (nx, ny, nz, 7)
        # the stored fields, mirrored, are the kernel fields CFD-DEM's mirrored particles deposit
        want_alpha = solid_fraction(pos, f.diameters, f.grid, f.kernel_sigma)
        np.testing.assert_allclose(norm.field_back("solid_fraction", grid[..., 3:4]), want_alpha, atol=1e-6)
        want_flux = solids_flux(pos, disp, f.diameters, f.grid, f.kernel_sigma, f.dt)
        np.testing.assert_allclose(norm.field_back("solids_flux", grid[..., 4:]), want_flux, atol=1e-6)
        want_c = mixing_concentration(pos, f.diameters, f.labels, f.grid, f.mixing_sigma, f.prior)
        np.testing.assert_allclose(norm.field_back("mixing", item["mixing_grid"][0, ..., None].double().numpy()),
                                   want_c, atol=1e-6)
        np.testing.assert_allclose(norm.field_back("fluid_velocity", grid[..., :3]),
                                   mirror_grid(f.fluid_velocity(t), vector=True), atol=1e-5)
        # the target: the next state of the same mirrored particles
        np.testing.assert_allclose(norm.positions_back(item["target_pos"][0].double().numpy()),
                                   mirror_points(f.positions(t + 1), lo, hi), atol=1e-7)
        target = item["target_fluid"][0].double().numpy().reshape(*f.grid.shape, 7)
        np.testing.assert_allclose(norm.field_back("solid_fraction", target[..., 3:4]),
                                   solid_fraction(mirror_points(f.positions(t + 1), lo, hi), f.diameters, f.grid,
                                                  f.kernel_sigma), atol=1e-6)


@pytest.mark.solver
def test_half_the_training_samples_are_mirrored_and_evaluation_never(fb_tiny_dataset: Path):
    dm = BedDataModule(str(fb_tiny_dataset), "fb_tiny", batch_size=2, mirror=True)
    dm.setup("fit")
    train = dm.datasets["train"]
    i = len(train) // 2
    s, t = train.items[i]
    with BedFile(dm.paths("train")[s]) as f:
        x = dm.norm.positions(f.positions(t))[:, 0]
    flipped = [not np.allclose(train.sample(i, np.random.default_rng(k))["particle_pos"][:, 0].numpy(), x,
                               atol=1e-6) for k in range(200)]
    assert 70 < sum(flipped) < 130  # binomial(200, 0.5): outside with probability < 1e-4
    assert not dm.datasets["val"].mirror and not dm.datasets["test"].mirror
    assert dm.checkpoint_metadata()["mirror"] is True


def test_a_mirror_option_that_is_not_a_boolean_is_refused(tmp_path: Path):
    with pytest.raises(ConfigError, match="data.datamodule.mirror"):
        BedDataModule(str(tmp_path), "fb_tiny", mirror="sometimes")
