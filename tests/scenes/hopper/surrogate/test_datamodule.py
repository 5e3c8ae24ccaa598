"""HopperDataModule targets on a real tiny LIGGGHTS dataset, checked against brute force."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes.hopper.dataset.store import HopperFile
from neuraldem.scenes.hopper.surrogate.datamodule import HopperDataModule

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
    active = np.flatnonzero(ds.active_mask())  # the held tail repeats the last snapshot
    for i in active[:: max(1, len(active) // 6)]:
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
    item = dm.datasets["val"][0]  # t = 0: full hopper, queries near the initial positions are occupied
    n_near = dm.n_queries - int(round(dm.box_fraction * dm.n_queries))
    assert dm.jitter_d < dm.occupancy_radius_d
    assert item["occupancy"][:n_near].min() == 1.0
    assert 0.0 in item["occupancy"][n_near:].tolist()  # the box has empty space


def test_query_points_do_not_depend_on_the_labels(dm: HopperDataModule, monkeypatch: pytest.MonkeyPatch):
    """The same sample drawn with the particles in place and with the hopper emptied: identical query points,
    different labels. Only the labels may depend on where the particles are."""
    ds = dm.datasets["val"]
    i = int(np.flatnonzero(ds.active_mask())[1])  # a snapshot with material in the hopper
    full = ds[i]
    f = ds._open(ds.items[i][0])[0]
    monkeypatch.setattr(f, "positions", lambda k=None: np.full((f.n_particles, 3), np.nan))
    empty = ds[i]
    torch.testing.assert_close(full["occupancy_pos"], empty["occupancy_pos"])
    assert full["occupancy"].sum() > 0 and empty["occupancy"].sum() == 0


def test_mean_label_at_initial_positions_is_the_occupied_share(dm: HopperDataModule):
    """Queries at the initial positions (no jitter): the share labelled occupied estimates the DEM count / N0
    without bias, so a model fitting the labels reproduces the counts the metrics are made of."""
    from neuraldem.scenes.hopper.dataset.fields import nearest_particle
    from neuraldem.scenes.hopper.surrogate.datamodule import occupancy_labels, occupancy_queries

    rec = dm.records("train")[0]
    with HopperFile(dm.dataset_dir / rec.file) as f:
        initial = f.initial_positions()
        k = f.n_snapshots // 2
        pos = f.positions(k)
    radius = dm.occupancy_radius_d * dm.particle_diameter
    present = pos[np.isfinite(pos[:, 0])]
    share = nearest_particle(initial, pos, radius)[0].mean()  # what the metrics count at this snapshot
    assert 0.05 < share < 0.95
    q = occupancy_queries(np.random.default_rng(0), initial, 20000, 0, 0.0, np.array(dm.norm.box_lo),
                          np.array(dm.norm.box_hi))
    labels = occupancy_labels(q, present, radius)
    sigma = np.sqrt(share * (1 - share) / len(q))
    assert abs(labels.mean() - share) < 4 * sigma


def test_training_draws_a_tail_share_from_the_held_final_state(dm: HopperDataModule):
    from neuraldem.scenes.hopper.surrogate.datamodule import tail_weights

    active = dm.datasets["train"].active_mask()
    assert active.any() and (~active).any()
    w = tail_weights(active, 0.1)
    assert w[~active].sum() / w.sum() == pytest.approx(0.1)
    assert np.all(tail_weights(np.ones(4, dtype=bool), 0.1) == 1.0)


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
    with pytest.raises(ConfigError, match=r"data\.datamodule\.fold=5 is invalid: must be < n_folds=5"):
        HopperDataModule(str(hopper_tiny_dataset), "hopper_tiny", ["t", "alpha"], fold=5)
    with pytest.raises(ConfigError, match=r"data\.datamodule\.n_folds=1"):
        HopperDataModule(str(hopper_tiny_dataset), "hopper_tiny", ["t", "alpha"], n_folds=1, fold=0)
    with pytest.raises(ConfigError, match=r"data\.datamodule\.tail_share"):
        HopperDataModule(str(hopper_tiny_dataset), "hopper_tiny", ["t", "alpha"], tail_share=1.5)


def test_too_few_runs_for_cross_validation_say_so_in_one_line(hopper_tiny_dataset: Path):
    dm = HopperDataModule(str(hopper_tiny_dataset), "hopper_tiny", ["t", "alpha"], fold=0, n_folds=5)
    with pytest.raises(DataError) as err:
        dm.setup()
    msg = str(err.value)
    assert "too few for 5-fold random cross-validation" in msg and "datagen" in msg and "\n" not in msg


def test_cross_validation_fold_from_the_usable_runs(hopper_tiny_dataset: Path):
    dm = HopperDataModule(str(hopper_tiny_dataset), "hopper_tiny", ["t", "alpha"], fold=1, n_folds=2)
    dm.setup()
    ids = dm.split_ids
    assert set(ids["test"]).isdisjoint(ids["train"] + ids["val"]) and ids["val"]
    meta = dm.checkpoint_metadata()
    assert meta["fold"] == 1 and meta["split_ids"] == ids


def test_query_points_outside_the_box(dm: HopperDataModule):
    with pytest.raises(DataError, match="outside the scene box"):
        dm.norm.check_inside(np.array([[0.0, 0.0, 5.0]]), "evaluation query")


def test_folds_over_the_first_n_sims_wait_for_pending_runs(hopper_tiny_dataset: Path, tmp_path: Path):
    """n_sims fixes the runs a cross-validation sees while datagen adds more; a pending one is refused."""
    import shutil

    from neuraldem.data.manifest import Manifest
    from neuraldem.scenes.hopper.surrogate.datamodule import cv_records

    m = Manifest.load(hopper_tiny_dataset)
    assert [r.sim_id for r in cv_records(m, 5, hopper_tiny_dataset)] == [r.sim_id for r in m.simulations[:5]
                                                                         if r.usable]
    other = tmp_path / "ds"
    shutil.copytree(hopper_tiny_dataset, other)
    m.simulations[3].status = "pending"
    with pytest.raises(DataError, match=r"of the first 5 simulations .* are not finished \(e\.g\. sim_0003\)"):
        cv_records(m, 5, other)
    with pytest.raises(DataError, match="n_sims=99"):
        cv_records(m, 99, other)
