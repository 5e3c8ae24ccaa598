import numpy as np
import pytest

from neuraldem.errors import ConfigError, DataError
from neuraldem.gns.datamodule import GnsDataModule, GnsNormalizer, ParticleRun, random_walk_noise


def test_noise_is_a_random_walk():
    n = random_walk_noise(np.random.default_rng(0), 20000, 5, 0.1)
    std = n.std(axis=(0, 2))
    assert np.all(np.diff(std) > 0)  # grows with the history index
    np.testing.assert_allclose(std, 0.1 * np.sqrt(np.arange(1, 6) / 5), rtol=0.03)
    steps = np.diff(n, axis=1)  # independent increments
    assert abs(np.corrcoef(steps[:, 0, 0], steps[:, 1, 0])[0, 1]) < 0.03


@pytest.mark.solver
@pytest.mark.parametrize("name", ["hopper_tiny", "fb_tiny"])
def test_sample_is_the_finite_difference_acceleration(name, request):
    dataset = request.getfixturevalue(f"{name}_dataset")
    dm = GnsDataModule(str(dataset), name, history=2)
    dm.setup()
    norm = dm.norm
    ds = dm.datasets["train"]
    s, t = ds.items[3]
    sample = ds[3]
    with ParticleRun(dataset / str(ds.records[s].file), dm.kind, dm.manifest.scene) as run:
        x = run.positions()
    present = np.isfinite(x[t]).all(axis=1)
    assert sample.num_nodes == present.sum() and sample.velocities.shape == (present.sum(), 2, 3)
    a = (x[t + 1] - 2 * x[t] + x[t - 1])[present] / norm.dt**2
    ok = sample.mask.numpy()
    np.testing.assert_allclose(norm.acceleration_back(sample.y.numpy())[ok], a[ok], rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(sample.pos.numpy(), x[t][present] / norm.length, rtol=1e-5)
    assert sample.wall_distance.shape == (present.sum(), 2 if name == "hopper_tiny" else 0)
    assert sample.scalars.shape == (1, len(dm.conditioning))


@pytest.mark.solver
def test_noise_keeps_the_target_consistent(fb_tiny_dataset):
    """One integrator step from the noisy inputs with the corrected target reaches the true next velocity."""
    clean = GnsDataModule(str(fb_tiny_dataset), "fb_tiny", history=3)
    clean.setup()
    noisy = GnsDataModule(str(fb_tiny_dataset), "fb_tiny", history=3, noise_std=0.3)
    noisy.setup()
    a, b = clean.datasets["train"][5], noisy.datasets["train"][5]
    norm = clean.norm
    std = np.asarray(norm.velocity_std)
    v_clean = a.velocities.numpy() * std + norm.velocity_mean
    v_noisy = b.velocities.numpy() * std + norm.velocity_mean
    diff = v_noisy - v_clean
    assert np.all(diff[:, -1].std(axis=0) > diff[:, 0].std(axis=0))  # noise grows along the history
    nxt_clean = v_clean[:, -1] + norm.acceleration_back(a.y.numpy()) * norm.dt
    nxt_noisy = v_noisy[:, -1] + norm.acceleration_back(b.y.numpy()) * norm.dt
    np.testing.assert_allclose(nxt_noisy, nxt_clean, atol=1e-3 * std.max())


@pytest.mark.solver
def test_normalisation_uses_the_training_split_only(hopper_tiny_dataset):
    dm = GnsDataModule(str(hopper_tiny_dataset), "hopper_tiny", history=2)
    dm.setup()
    m = dm.manifest
    train = [(hopper_tiny_dataset / str(r.file), r.conditioning()) for r in dm.records("train")]
    everything = [(hopper_tiny_dataset / str(r.file), r.conditioning()) for r in m.usable()]
    fit_train = GnsNormalizer.fit(train, "hopper", m.scene, 2, dm.conditioning)
    fit_all = GnsNormalizer.fit(everything, "hopper", m.scene, 2, dm.conditioning)
    assert dm.norm == fit_train and dm.norm != fit_all
    assert dm.checkpoint_metadata()["kind"] == "gns" and dm.checkpoint_metadata()["scene_kind"] == "hopper"


@pytest.mark.solver
@pytest.mark.parametrize(("kwargs", "key"), [
    ({"history": 0}, "data.datamodule.history"), ({"history": 99}, "data.datamodule.history"),
    ({"noise_std": 2.0}, "data.datamodule.noise_std"), ({"noise_std": -0.1}, "data.datamodule.noise_std"),
    ({"conditioning": ["t", "alpha"]}, "data.conditioning"),
    ({"conditioning": ["inlet_velocity"]}, "data.conditioning"),
    ({"split": "velocity"}, "data.split"), ({"batch_size": 0}, "data.datamodule.batch_size"),
])
def test_bad_values_end_in_one_line(hopper_tiny_dataset, kwargs, key):
    with pytest.raises(ConfigError) as err:
        GnsDataModule(str(hopper_tiny_dataset), "hopper_tiny", **kwargs).setup()
    assert key in str(err.value) and "\n" not in str(err.value)


@pytest.mark.solver
def test_history_longer_than_the_runs_is_refused(fb_tiny_dataset):
    with pytest.raises(ConfigError, match="data.datamodule.history=20"):
        GnsDataModule(str(fb_tiny_dataset), "fb_tiny", history=20).setup()


def test_other_kinds_are_refused(tmp_path):
    with pytest.raises(DataError):
        GnsDataModule(str(tmp_path), "nothing").setup()
