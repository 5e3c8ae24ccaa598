"""RefillDataModule on the real tiny refill dataset: targets relative to a random past reference time,
conditioning on dt_ref, new material out of the transport loss, and bad settings refused by key."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from neuraldem.errors import ConfigError
from neuraldem.scenes.hopper_refill.datamodule import RefillDataModule
from neuraldem.scenes.hopper_refill.targets import particle_targets

pytestmark = pytest.mark.solver


def make(dataset: Path, **kw) -> RefillDataModule:
    args = {"conditioning": ["dt_ref", "alpha", "mu_s", "mu_r"], "window": 0.25, "n_queries": 64, "batch_size": 2}
    args.update(kw)
    dm = RefillDataModule(str(dataset), "hopper_refill_tiny", **args)
    dm.setup()
    return dm


def test_sample_targets_match_the_particles(hopper_refill_tiny_dataset: Path):
    dm = make(hopper_refill_tiny_dataset)
    ds = dm.datasets["val"]
    norm = dm.norm
    i = len(ds) - 1  # a late snapshot: refilled material is present
    sample = ds[i]
    s, k = ds.items[i]
    k_ref = ds.reference_index(i, ds._rng(i))  # validation: the same draw as the sample
    f = ds._open(s)
    t, t_ref = float(f.times[k]), float(f.times[k_ref])
    assert 0 <= t - t_ref <= 0.25 + 1e-9
    assert float(sample["scalars"][0]) == pytest.approx((t - t_ref) / 0.25)
    # the particle queries are particle centres at t; recompute their targets directly
    pos = norm.positions_back(sample["particle_pos"].double().numpy())
    rows, pos_t = f.frame(k)
    nearest = np.argmin(np.linalg.norm(pos[:, None] - pos_t[None], axis=-1), axis=1)
    tg = particle_targets(t, t_ref, rows[nearest], pos_t[nearest], *f.frame(k_ref), f.insert_times)
    np.testing.assert_allclose(sample["residence"].numpy(), tg.residence / 0.25, atol=1e-6)
    assert sample["transport_mask"].numpy().tolist() == (~tg.new).tolist()
    old = ~tg.new
    np.testing.assert_allclose(norm.positions_back(sample["transport"].double().numpy())[old], tg.transport[old],
                               atol=1e-5)


def test_training_draws_the_reference_at_random(hopper_refill_tiny_dataset: Path):
    dm = make(hopper_refill_tiny_dataset)
    ds = dm.datasets["train"]
    i = len(ds) - 1
    dts = {round(float(ds[i]["scalars"][0]), 6) for _ in range(12)}
    assert len(dts) > 3  # t_ref varies between draws
    assert all(0.0 <= v <= 1.0 for v in dts)
    fixed = make(hopper_refill_tiny_dataset, random_reference=False).datasets["train"]
    assert {round(float(fixed[i]["scalars"][0]), 6) for _ in range(3)} == {1.0}  # always t - window
    batch = next(iter(dm.train_dataloader()))
    assert batch["transport_mask"].dtype == torch.bool and batch["scalars"].shape == (2, 4)


@pytest.mark.parametrize(("kw", "message"), [
    ({"conditioning": ["t", "alpha"]}, r"data.conditioning=\['t', 'alpha'\] is invalid: unknown name"),
    ({"conditioning": ["alpha", "dt_ref"]}, r"the first scalar must be the time 'dt_ref'"),
    ({"window": 0.07}, r"data.reference.window=0.07 is invalid: must be a positive multiple of the snapshot"),
    ({"window": 5.0}, r"data.reference.window=5.0 is invalid: longer than the simulations"),
    ({"random_reference": "yes"}, r"data.datamodule.random_reference='yes' is invalid: must be true or false"),
])
def test_bad_settings_name_the_key(hopper_refill_tiny_dataset: Path, kw, message):
    with pytest.raises(ConfigError, match=message):
        make(hopper_refill_tiny_dataset, **kw)
