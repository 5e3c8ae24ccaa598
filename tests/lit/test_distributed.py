"""Data-parallel pieces that need no second process: the global-batch loaders, the training draws, the checks
and the launcher's command (the runs themselves: tests/test_ddp.py)."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import pytest
import torch
from torch.utils.data import Dataset

from neuraldem.data.part_loaders import PartLoaders
from neuraldem.errors import ConfigError
from neuraldem.lit import distributed
from neuraldem.lit.distributed import TrainingDraws, child_command, rank_batch_size


class Numbers(Dataset):
    def __init__(self, n: int):
        self.n = n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, key):  # noqa: ANN001
        return getattr(key, "index", key)


class Loaders(PartLoaders):
    def __init__(self, rank: int = 0, world: int = 1, batch_size: int = 4) -> None:
        super().__init__()
        self.datasets = {"train": Numbers(18), "val": Numbers(11)}
        self.batch_size, self.num_workers, self.seed = batch_size, 0, 5
        self.trainer = SimpleNamespace(global_rank=rank, world_size=world) if world > 1 else None


def test_each_step_of_two_processes_is_the_one_process_batch():
    one = [b.tolist() for b in Loaders().train_dataloader()]
    ranks = [[b.tolist() for b in Loaders(r, 2).train_dataloader()] for r in range(2)]
    assert len(ranks[0]) == len(ranks[1]) == len(one) == 4  # 18 samples, global batches of 4
    for step, batch in enumerate(one):
        assert sorted(ranks[0][step] + ranks[1][step]) == sorted(batch)
        assert ranks[0][step] == batch[0::2] and ranks[1][step] == batch[1::2]


def test_validation_deals_out_whole_one_process_batches():
    one = [b.tolist() for b in Loaders().val_dataloader()]  # 11 samples: 4 + 4 + 3
    ranks = [[b.tolist() for b in Loaders(r, 2).val_dataloader()] for r in range(2)]
    assert ranks == [one[0::2], one[1::2]]
    few = [[b.tolist() for b in Loaders(r, 4, batch_size=4).val_dataloader()] for r in range(4)]
    assert all(f == one for f in few)  # fewer batches than processes: every process scores them all


def test_a_global_batch_that_does_not_split_is_refused():
    with pytest.raises(ConfigError, match=r"batch_size=6 is invalid: it is the global batch.* multiple of 4.*"
                                          r"batch_size=4"):
        Loaders(0, 4, batch_size=6).train_dataloader()
    assert rank_batch_size(8, 4) == 2 and rank_batch_size(5, 1) == 5


def test_training_draws_of_a_row_do_not_depend_on_the_processes():
    one = TrainingDraws(seed=7, batch=3).rows("noise", 4, (5,))
    for rank in range(2):
        share = TrainingDraws(seed=7, batch=3, rank=rank, world=2).rows("noise", 2, (5,))
        torch.testing.assert_close(share, one[rank::2], rtol=0, atol=0)
    assert not torch.equal(TrainingDraws(seed=7, batch=4).rows("noise", 4, (5,)), one)  # next batch: new draws
    members = TrainingDraws(seed=7, batch=3).rows("noise", 4, (5,), members=2)
    torch.testing.assert_close(members[:4], one, rtol=0, atol=0)  # member-major, member 0 first
    assert not torch.equal(members[4:], one)
    same = TrainingDraws(seed=7, batch=3, rank=1, world=2)
    assert torch.multinomial(torch.ones(9), 1, generator=same.batch_generator("unroll")) == \
        torch.multinomial(torch.ones(9), 1, generator=TrainingDraws(7, 3).batch_generator("unroll"))


def test_children_run_the_saved_job_config_in_the_same_folder(tmp_path):
    cmd = child_command(tmp_path / "job.yaml", "/runs/it's here")
    assert cmd[1:3] == ["-m", "neuraldem.train"]
    assert f"--config-dir={tmp_path}" in cmd and "--config-name=job" in cmd
    assert "hydra.run.dir='/runs/it\\'s here'" in cmd and "hydra.output_subdir=null" in cmd


def _trainer(devices: int, strategy: object = "ddp"):
    from omegaconf import OmegaConf

    from neuraldem.config.build import build_trainer

    cfg = {"_target_": "lightning.pytorch.Trainer", "accelerator": "cpu", "devices": devices, "strategy": strategy,
           "logger": False, "enable_checkpointing": False}
    return build_trainer(OmegaConf.create(cfg), [], [], strategies=distributed.STRATEGIES)


def _job(batch_size: int = 4, devices: int = 2):
    from omegaconf import OmegaConf

    return OmegaConf.create({"trainer": {"devices": devices}, "data": {"datamodule": {"batch_size": batch_size}},
                             "paths": {"output_dir": "/tmp/x"}})


def test_more_processes_than_cores_warns(monkeypatch, caplog):
    monkeypatch.setattr(distributed, "cpu_count", lambda: 1)
    trainer = _trainer(2)
    assert isinstance(trainer.strategy, distributed.JobDDPStrategy)  # trainer.strategy=ddp: our launcher
    with caplog.at_level(logging.WARNING, logger="neuraldem.lit.distributed"):
        distributed.prepare(trainer, _job())
    assert "2 training processes on this node (trainer.devices=2) but only 1 CPU cores" in caplog.text
    assert trainer.strategy.job_config is not None
    monkeypatch.setattr(distributed, "cpu_count", lambda: 2)
    caplog.clear()
    distributed.prepare(trainer, _job())
    assert "CPU cores" not in caplog.text
    with pytest.raises(ConfigError, match=r"data.datamodule.batch_size=5 is invalid.*multiple of 2"):
        distributed.prepare(trainer, _job(batch_size=5))


@pytest.mark.parametrize("key,value", [("devices", 0), ("devices", -2), ("devices", "two"), ("devices", [0, 0]),
                                       ("devices", True), ("num_nodes", 0), ("use_distributed_sampler", True)])
def test_bad_process_counts_are_refused(key: str, value: object):
    from omegaconf import OmegaConf

    from neuraldem.config.build import check_trainer

    with pytest.raises(ConfigError, match=f"trainer.{key}="):
        check_trainer(OmegaConf.create({key: value}))
    for ok in (1, 4, -1, "auto", "2", "0,1", [0, 1]):
        check_trainer(OmegaConf.create({"devices": ok}))


class TwoProcesses:
    """A strategy stand-in for one of two processes: `reduce(.., "mean")` averages with the other's values."""

    def __init__(self, others: list[torch.Tensor]):
        self.others = list(others)

    def reduce(self, value: torch.Tensor, reduce_op: str) -> torch.Tensor:
        assert reduce_op == "mean"
        return (value + self.others.pop(0)) / 2


@pytest.mark.solver
def test_a_masked_mean_over_two_processes_is_the_one_process_mean(tiny_checkpoint):
    """The hopper's transport and residence losses average over present particles; with halves of unequal counts
    (here an empty hopper in one half), the mean of the two processes' losses and gradients (what DDP averages)
    is the one-process loss and gradient only with the shared count."""
    from neuraldem.scenes.hopper.surrogate.module import HopperModule

    module = HopperModule.load_from_checkpoint(tiny_checkpoint)
    g, q = torch.Generator().manual_seed(0), 16
    batch = {"scalars": torch.rand(4, module.net.n_scalars, generator=g),
             "occupancy_pos": torch.rand(4, q, 3, generator=g),
             "occupancy": (torch.rand(4, q, generator=g) > 0.5).float(),
             "particle_pos": torch.rand(4, q, 3, generator=g), "transport": torch.rand(4, q, 3, generator=g),
             "residence": torch.rand(4, q, generator=g), "particle_mask": torch.ones(4, q, dtype=torch.bool)}
    batch["particle_mask"][1] = False  # an empty hopper: 16 + 0 particles on one process, 16 + 16 on the other
    halves = [{k: v[[r, r + 2]] for k, v in batch.items()} for r in range(2)]
    counts = [h["particle_mask"].float().sum() for h in halves]

    def grads(loss: torch.Tensor) -> list[torch.Tensor]:
        return [p.clone() for p in torch.autograd.grad(loss, list(module.parameters()), allow_unused=True,
                                                          materialize_grads=True)]

    full = module.losses(batch)
    full_grads = grads(full["loss"])
    naive = [module.losses(h) for h in halves]
    naive_mean = float((naive[0]["transport"] + naive[1]["transport"]).detach()) / 2
    assert naive_mean != pytest.approx(float(full["transport"].detach()), rel=1e-3)  # each process's own count
    shared = []
    for r, half in enumerate(halves):
        other = counts[1 - r]
        module._trainer = SimpleNamespace(training=True, world_size=2, strategy=TwoProcesses([other, other]))
        shared.append(module.losses(half))
    module._trainer = None
    for key in ("transport", "residence", "occupancy", "loss"):
        torch.testing.assert_close((shared[0][key] + shared[1][key]) / 2, full[key], rtol=1e-6, atol=0)
    averaged = [(a + b) / 2 for a, b in zip(grads(shared[0]["loss"]), grads(shared[1]["loss"]), strict=True)]
    for a, b in zip(averaged, full_grads, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-7)
