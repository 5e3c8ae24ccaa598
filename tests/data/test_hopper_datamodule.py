"""HopperDataModule targets on a real tiny LIGGGHTS dataset, checked against brute force."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from neuraldem.data.hopper_datamodule import HopperDataModule
from neuraldem.data.hopper_store import HopperFile
from neuraldem.errors import ConfigError, DataError

pytestmark = pytest.mark.solver


@pytest.fixture(scope="module")
def dm(hopper_tiny_dataset: Path) -> HopperDataModule:
    module = HopperDataModule(str(hopper_tiny_dataset), "hopper_tiny", ["t", "alpha", "mu_s", "mu_r", "theta"],
                              batch_size=2, n_queries=64)
    module.setup("fit")
    return module


def test_targets_match_brute_force(dm: HopperDataModule):
    ds = dm.datasets["val"]
    norm = dm.norm
    radius = dm.occupancy_radius_d * dm.particle_diameter
    checked = 0
    for i in range(0, len(ds), max(1, len(ds) // 6)):
        item = ds[i]
        s, k = ds.items[i]
        with HopperFile(ds.dir / ds.records[s].file) as f:
            pos = f.positions(min(k, f.n_snapshots - 1))
            initial, exits = f.initial_positions(), f.exit_times
        t = k * ds.dt
        present = np.isfinite(pos[:, 0])
        # occupancy: brute-force distance to every particle present at t
        q = norm.positions_back(item["occupancy_pos"].double().numpy())
        d = np.linalg.norm(q[:, None, :] - pos[None, present, :], axis=-1).min(axis=1) if present.any() else \
            np.full(len(q), np.inf)
        np.testing.assert_array_equal(item["occupancy"].numpy() > 0.5, d <= radius + 1e-6)
        if not present.any():
            assert not item["particle_mask"].any()
            continue
        # transport / residence: find each queried particle by its position
        p = norm.positions_back(item["particle_pos"].double().numpy())
        idx = np.linalg.norm(p[:, None, :] - np.nan_to_num(pos, nan=1e9)[None], axis=-1).argmin(axis=1)
        np.testing.assert_allclose(norm.positions_back(item["transport"].double().numpy()), initial[idx],
                                   atol=1e-6)
        expected = np.where(np.isfinite(exits[idx]), exits[idx], norm.horizon) - t
        np.testing.assert_allclose(norm.time_back(item["residence"].double().numpy()), expected, atol=1e-5)
        checked += 1
    assert checked >= 3


def test_occupancy_true_at_centres_false_far_away(dm: HopperDataModule):
    item = dm.datasets["val"][0]  # t = 0: full hopper
    n_near = dm.n_queries - int(round(dm.negative_fraction * dm.n_queries))
    assert item["occupancy"][:n_near].min() == 1.0  # jittered centres are inside the radius
    assert 0.0 in item["occupancy"][n_near:].tolist()  # the box has empty space


def test_scalars_normalised_on_train_split(dm: HopperDataModule):
    loader = dm.train_dataloader()
    batch = next(iter(loader))
    assert batch["scalars"].shape == (2, 5) and batch["occupancy_pos"].shape == (2, 64, 3)
    assert torch.all((batch["occupancy_pos"] >= 0) & (batch["occupancy_pos"] <= 1))
    train_alpha = [r.params["alpha"] for r in dm.records("train")]
    assert dm.norm.scalar_lo["alpha"] == min(train_alpha) and dm.norm.scalar_hi["alpha"] == max(train_alpha)


def test_bad_config_values(hopper_tiny_dataset: Path, tmp_path: Path):
    with pytest.raises(ConfigError, match=r"data\.datamodule\.batch_size=-1"):
        HopperDataModule(str(hopper_tiny_dataset), "hopper_tiny", ["t", "alpha"], batch_size=-1)
    with pytest.raises(ConfigError, match="unknown name"):
        HopperDataModule(str(hopper_tiny_dataset), "hopper_tiny", ["t", "ffc"])
    with pytest.raises(ConfigError, match="time 't'"):
        HopperDataModule(str(hopper_tiny_dataset), "hopper_tiny", ["alpha", "t"])
    with pytest.raises(DataError, match="no dataset at"):
        HopperDataModule(str(tmp_path), "hopper_tiny", ["t", "alpha"]).setup()


def test_query_points_outside_the_box(dm: HopperDataModule):
    with pytest.raises(DataError, match="outside the scene box"):
        dm.norm.check_inside(np.array([[0.0, 0.0, 5.0]]), "evaluation query")
