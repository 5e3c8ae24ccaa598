"""BedDataModule on the real fb_tiny DPMFoam dataset: samples against the files, normalisation from
the training split only, push-forward / noise options, and bad input in one clear error."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes.fluidized_bed.dataset.fields import solids_flux
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.datamodule import BedDataModule
from neuraldem.scenes.fluidized_bed.surrogate.normalization import BedNormalizer
from tests.helpers import copy_dataset, rerecord_checksum

pytestmark = pytest.mark.solver


def _read(path: Path, what: str):
    """An attribute of a trajectory file, or the result of calling it (e.g. a whole field)."""
    with BedFile(path) as f:
        value = getattr(f, what)
        return value() if callable(value) else value


def _dm(dataset: Path, **kwargs) -> BedDataModule:
    dm = BedDataModule(str(dataset), "fb_tiny", **({"batch_size": 2} | kwargs))
    dm.setup("fit")
    return dm


@pytest.mark.parametrize("k", [1, 3])
def test_samples_are_the_files_states_and_targets(fb_tiny_dataset: Path, k: int):
    dm = _dm(fb_tiny_dataset, push_forward_steps=k, solids_flux=k == 3)
    ds, norm = dm.datasets["train"], dm.norm
    assert len(ds) == sum(_read(p, "n_snapshots") - k for p in dm.paths("train"))
    channels = 7 if k == 3 else 4
    for i in (0, 1, len(ds) - 1):  # t = 0 (no previous displacement), t = 1, the last sample
        item, (s, t) = ds[i], ds.items[i]
        with BedFile(dm.paths("train")[s]) as f:
            pos, disp_in = f.positions(t), (f.displacement(t - 1) if t > 0 else np.zeros((f.n_particles, 3)))
            np.testing.assert_allclose(norm.positions_back(item["particle_pos"].double().numpy()), pos, atol=1e-7)
            np.testing.assert_allclose(norm.field_back("displacement", item["particle_features"].double().numpy()),
                                       disp_in, atol=1e-9)
            grid = item["grid"].double().numpy()  # (channels, nx, ny, nz)
            assert grid.shape[0] == channels
            np.testing.assert_allclose(norm.field_back("fluid_velocity", np.moveaxis(grid[:3], 0, -1)),
                                       f.fluid_velocity(t), atol=1e-5)
            np.testing.assert_allclose(norm.field_back("solid_fraction", grid[3][..., None]), f.solid_fraction(t),
                                       atol=1e-6)
            np.testing.assert_allclose(norm.field_back("mixing", item["mixing_grid"][0, ..., None].double().numpy()),
                                       f.mixing(t), atol=1e-6)
            assert float(item["solid_volume"]) == pytest.approx(float(f.solid_fraction(t).sum()), rel=1e-9)
            if channels == 7:  # the solids flux of the last step, as fb_fields computes it from the particles
                want = np.zeros((*f.grid.shape, 3)) if t == 0 else solids_flux(
                    pos, disp_in, f.diameters, f.grid, f.kernel_sigma, f.dt)
                np.testing.assert_allclose(norm.field_back("solids_flux", np.moveaxis(grid[4:], 0, -1)), want,
                                           atol=1e-6)
            # targets at every t + j, j = 1 .. k: the fields, and the displacement that brought each particle to
            # its position at t + j
            for j in range(1, k + 1):
                tk = t + j
                np.testing.assert_allclose(norm.positions_back(item["target_pos"][j - 1].double().numpy()),
                                           f.positions(tk), atol=1e-7)
                np.testing.assert_allclose(norm.field_back("displacement",
                                                           item["target_particles"][j - 1].double().numpy()),
                                           f.displacement(tk - 1), atol=1e-9)
                target = item["target_fluid"][j - 1].double().numpy().reshape(*f.grid.shape, channels)
                np.testing.assert_allclose(norm.field_back("solid_fraction", target[..., 3:4]), f.solid_fraction(tk),
                                           atol=1e-6)
                np.testing.assert_allclose(norm.field_back("fluid_velocity", target[..., :3]), f.fluid_velocity(tk),
                                           atol=1e-5)
                np.testing.assert_allclose(norm.field_back("mixing", item["target_mixing"][j - 1].double().numpy())
                                           .reshape(f.grid.shape), f.mixing(tk), atol=1e-6)
        assert item["scalars"].shape == (1,)


def test_normalisation_comes_from_the_training_split_only(fb_tiny_dataset: Path):
    dm = _dm(fb_tiny_dataset)
    train, test = dm.paths("train"), dm.paths("test")
    assert train and test and not set(train) & set(test)
    norm = dm.norm
    train_v = sorted({_read(p, "inlet_velocity") for p in train})
    assert (norm.velocity_lo, norm.velocity_hi) == (train_v[0], train_v[-1])

    def alpha_stats(paths):
        values = np.concatenate([_read(p, "solid_fraction").ravel() for p in paths])
        return values.mean(), values.std()

    mean, std = alpha_stats(train)
    assert norm.mean["solid_fraction"][0] == pytest.approx(mean, rel=1e-9)
    assert norm.std["solid_fraction"][0] == pytest.approx(std, rel=1e-6)
    everything = BedNormalizer.fit(train + test)  # what leaking the held-out velocity would give
    assert everything.mean["fluid_velocity"][2] != pytest.approx(norm.mean["fluid_velocity"][2], rel=1e-3)
    assert everything.velocity_hi > norm.velocity_hi
    assert dm.checkpoint_metadata()["normalizer"] == norm.to_dict()


def test_one_step_change_statistics(fb_tiny_dataset: Path):
    norm = _dm(fb_tiny_dataset).norm
    train = _dm(fb_tiny_dataset).paths("train")
    diffs = np.concatenate([np.diff(_read(p, "solid_fraction"), axis=0).ravel() for p in train])
    assert norm.step_rms["solid_fraction"][0] == pytest.approx(np.sqrt(np.mean(diffs**2)), rel=1e-6)
    scale = norm.step_scale("solid_fraction")[0]  # in model units: relative to the field's own spread
    assert scale == pytest.approx(norm.step_rms["solid_fraction"][0] / norm.std["solid_fraction"][0])
    assert 0 < scale < 1  # the solid fraction changes by a fraction of its spread per step
    velocity = norm.step_scale("fluid_velocity")
    assert velocity[1] == 0.01  # the y velocity of the pseudo-2D bed never changes: the floor, not 0
    old = BedNormalizer.from_dict({k: v for k, v in norm.to_dict().items() if k != "step_rms"})
    with pytest.raises(DataError, match="no one-step statistics.*model.residual"):
        old.step_scale("mixing")


def test_noise_only_on_training_inputs(fb_tiny_dataset: Path):
    torch.manual_seed(0)
    noisy, clean = _dm(fb_tiny_dataset, input_noise=0.05), _dm(fb_tiny_dataset)
    a, b = noisy.datasets["train"][3], clean.datasets["train"][3]
    diff = (a["grid"] - b["grid"]).numpy()
    assert diff.std() == pytest.approx(0.05, rel=0.2)
    assert torch.equal(a["target_fluid"], b["target_fluid"]) and torch.equal(a["particle_pos"], b["particle_pos"])
    assert torch.equal(noisy.datasets["test"][0]["grid"], clean.datasets["test"][0]["grid"])
    assert noisy.datasets["test"].steps == 1 and noisy.datasets["test"].noise == 0.0


def test_particle_subsets(fb_tiny_dataset: Path):
    dm = _dm(fb_tiny_dataset, particles_per_sample=64)
    item = dm.datasets["test"][0]
    assert item["particle_pos"].shape == (64, 3) and item["target_pos"].shape == (1, 64, 3)
    assert torch.equal(item["particle_pos"], dm.datasets["test"][0]["particle_pos"])  # evaluation: repeatable
    batch = next(iter(dm.train_dataloader()))
    assert batch["particle_pos"].shape == (2, 64, 3) and batch["grid"].shape == (2, 4, 6, 1, 15)


def test_solids_flux_needs_its_statistics(fb_tiny_dataset: Path):
    norm = _dm(fb_tiny_dataset).norm  # fitted without the flux
    with pytest.raises(DataError, match="no statistics for 'solids_flux'.*solids_flux=true"):
        norm.field("solids_flux", np.zeros((2, 3)))
    with pytest.raises(ConfigError, match=r"data\.datamodule\.solids_flux='yes' is invalid"):
        BedDataModule(str(fb_tiny_dataset), "fb_tiny", solids_flux="yes")


def test_bad_config_values(fb_tiny_dataset: Path):
    with pytest.raises(ConfigError, match=r"data\.datamodule\.input_noise=-0\.1 is invalid"):
        BedDataModule(str(fb_tiny_dataset), "fb_tiny", input_noise=-0.1)
    with pytest.raises(ConfigError, match=r"data\.datamodule\.push_forward_steps=0 is invalid"):
        BedDataModule(str(fb_tiny_dataset), "fb_tiny", push_forward_steps=0)
    with pytest.raises(ConfigError, match=r"push_forward_steps=100 is invalid: must be <= 64"):
        BedDataModule(str(fb_tiny_dataset), "fb_tiny", push_forward_steps=100)
    with pytest.raises(ConfigError, match=r"push_forward_steps=25 is invalid: the shortest training trajectory"):
        _dm(fb_tiny_dataset, push_forward_steps=25)
    with pytest.raises(ConfigError, match=r"unknown name\(s\) \['packing'\]"):
        BedDataModule(str(fb_tiny_dataset), "fb_tiny", conditioning=["packing"])
    with pytest.raises(ConfigError, match=r"data\.split='random' is invalid"):
        BedDataModule(str(fb_tiny_dataset), "fb_tiny", split="random")
    with pytest.raises(ConfigError, match=r"particles_per_sample=0 is invalid"):
        BedDataModule(str(fb_tiny_dataset), "fb_tiny", particles_per_sample=0)


def test_dataset_of_another_kind(fb_tiny_dataset: Path, tmp_path: Path):
    ds = copy_dataset(fb_tiny_dataset, tmp_path / "ds")
    manifest = json.loads((ds / "manifest.json").read_text())
    manifest["kind"] = "hopper"
    (ds / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DataError, match="holds 'hopper' data, not fluidized_bed data"):
        _dm(ds)


@pytest.mark.parametrize("sim", ["sim_0000", "sim_0002"])  # a training file, a held-out file
def test_nan_in_a_dataset_file_is_named(fb_tiny_dataset: Path, tmp_path: Path, sim: str):
    ds = copy_dataset(fb_tiny_dataset, tmp_path / "ds")
    with h5py.File(ds / "sims" / f"{sim}.h5", "r+") as f:
        f["snapshots/fluid_velocity"][5, 2, 0, 3, 1] = np.nan
    rerecord_checksum(ds, ds / "sims" / f"{sim}.h5")
    with pytest.raises(DataError, match=rf"{sim}\.h5: /snapshots/fluid_velocity has NaN or inf values"):
        _dm(ds)


def test_runs_from_repeats_a_checkpoints_runs(fb_tiny_dataset: Path, fb_tiny_checkpoint: Path, tmp_path: Path):
    """A run can train on the runs an earlier one had (the checkpoint's split_ids, or a JSON of them), so an
    ablation stays paired while datagen adds trajectories; runs that are not finished in that part are refused."""
    recorded = torch.load(fb_tiny_checkpoint, weights_only=False)["hyper_parameters"]["metadata"]["split_ids"]
    dm = _dm(fb_tiny_dataset, runs_from=str(fb_tiny_checkpoint))
    assert {p: [r.sim_id for r in dm.records(p)] for p in recorded} == recorded
    assert dm.checkpoint_metadata()["split_ids"] == recorded
    fewer = dict(recorded, train=recorded["train"][:1])
    (tmp_path / "ids.json").write_text(json.dumps(fewer))
    dm = _dm(fb_tiny_dataset, runs_from=str(tmp_path / "ids.json"))
    assert [r.sim_id for r in dm.records("train")] == recorded["train"][:1]
    assert len(dm.datasets["train"].records) == 1
    stolen = dict(recorded, train=recorded["train"] + recorded["test"])
    (tmp_path / "stolen.json").write_text(json.dumps(stolen))
    with pytest.raises(DataError, match=r"stolen\.json: run 'sim_\d+' \(train\) is not a finished train run"):
        _dm(fb_tiny_dataset, runs_from=str(tmp_path / "stolen.json"))
    with pytest.raises(ConfigError, match=r"data\.datamodule\.runs_from=.*nothing\.ckpt is invalid: no such file"):
        _dm(fb_tiny_dataset, runs_from=str(tmp_path / "nothing.ckpt"))
    (tmp_path / "empty.json").write_text(json.dumps({"val": []}))
    with pytest.raises(ConfigError, match=r"runs_from=.*empty\.json is invalid: no list of 'train' run ids"):
        _dm(fb_tiny_dataset, runs_from=str(tmp_path / "empty.json"))
