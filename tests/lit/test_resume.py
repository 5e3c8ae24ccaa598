"""Kill a training run, resume it from its checkpoint, and get the weights of a run that was never killed."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import Dataset

from neuraldem.data.part_loaders import PartLoaders
from neuraldem.lit.resume import ExactResume
from tests.helpers import REPO, run_module


def draws() -> tuple[float, float, float]:
    return float(torch.rand(())), float(np.random.random()), random.random()


def test_rng_states_travel_in_a_weights_only_checkpoint(tmp_path: Path):
    cb, checkpoint = ExactResume(), {}
    cb.on_save_checkpoint(None, None, checkpoint)  # type: ignore[arg-type]
    expected = draws()
    torch.save(checkpoint, tmp_path / "c.ckpt")
    loaded = torch.load(tmp_path / "c.ckpt", weights_only=True)  # how Lightning reads checkpoints
    draws(), draws()  # a new process would have drawn anything
    cb.on_load_checkpoint(None, None, loaded)  # type: ignore[arg-type]
    assert draws() != expected  # not restored yet: that happens just before the first resumed step
    cb.on_train_start(None, None)  # type: ignore[arg-type]
    assert draws() == expected


class Indices(Dataset):
    def __len__(self) -> int:
        return 10

    def __getitem__(self, key):  # noqa: ANN001
        return key.index


class Loaders(PartLoaders):
    def __init__(self) -> None:
        super().__init__()
        self.datasets, self.batch_size, self.num_workers, self.seed = {"train": Indices()}, 3, 0, 7


def epoch_batches(dm: Loaders, epoch: int) -> list[list[int]]:
    loader = dm.train_dataloader()
    loader.sampler.set_epoch(epoch)
    return [b.tolist() for b in loader]


def test_a_restored_datamodule_starts_at_the_saved_batch():
    reference = Loaders()
    epoch1, epoch2 = epoch_batches(reference, 1), epoch_batches(reference, 2)
    assert len(epoch1) == 3  # 10 samples, batches of 3, the partial one dropped
    resumed = Loaders()
    resumed.load_state_dict({"train_position": {"epoch": 1, "batches_done": 2}})
    assert [b.tolist() for b in resumed.train_dataloader()] == epoch1[2:]
    at_end = Loaders()  # saved after the epoch's last batch: the next epoch, from its start
    at_end.load_state_dict({"train_position": {"epoch": 1, "batches_done": 3}})
    assert [b.tolist() for b in at_end.train_dataloader()] == epoch2


def final_state(run: Path) -> dict:
    ckpt = torch.load(run / "checkpoints" / "latest.ckpt", map_location="cpu", weights_only=False)
    return ckpt


def assert_same_training_state(a: dict, b: dict) -> None:
    assert a["global_step"] == b["global_step"]
    for key, value in a["state_dict"].items():
        torch.testing.assert_close(b["state_dict"][key], value, rtol=0, atol=0, msg=key)
    for sa, sb in zip(a["optimizer_states"][0]["state"].values(), b["optimizer_states"][0]["state"].values(),
                      strict=True):
        torch.testing.assert_close(sb["exp_avg"], sa["exp_avg"], rtol=0, atol=0)


# 9 batches per epoch at batch size 64: the runs cross two epoch ends; a checkpoint every 2 steps
HOPPER = ("experiment=hopper_quickstart", "logger=none", "evaluate=false", "trainer.max_steps=20",
          "trainer.val_check_interval=2", "data.datamodule.batch_size=64", "data.datamodule.n_queries=128",
          "callbacks.progress=null", "trainer.enable_model_summary=false")


def test_training_killed_at_random_points_equals_an_uninterrupted_run(hopper_tiny_dataset: Path, tmp_path: Path):
    """SIGKILL at seeded random moments after each new checkpoint (mid-step, mid-validation, mid-save), resume
    from latest.ckpt each time: the final weights and optimizer state equal an uninterrupted run's, bit for bit.
    One loader worker, so samples are prefetched by another process."""
    args = (*HOPPER, f"data.dataset_dir={hopper_tiny_dataset}", "data.datamodule.num_workers=1")
    env = {"NEURALDEM_DATA": str(tmp_path)}
    ref = run_module("neuraldem", "train", *args, f"hydra.run.dir={tmp_path}/ref", env=env)
    assert ref.returncode == 0, ref.stdout + ref.stderr

    run, latest = tmp_path / "killed", tmp_path / "killed" / "checkpoints" / "latest.ckpt"
    rng, kills, steps_at_kill = np.random.default_rng(22), 0, []
    for _ in range(3):
        resume = [f"ckpt_path={latest}"] if latest.exists() else []
        before = latest.stat().st_mtime_ns if latest.exists() else None
        proc = subprocess.Popen([sys.executable, "-m", "neuraldem", "train", *args, f"hydra.run.dir={run}", *resume],
                                cwd=REPO, env=dict(os.environ, **env), stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True)
        deadline = time.monotonic() + 300
        while proc.poll() is None and time.monotonic() < deadline:  # wait for a new checkpoint, then a bit
            if latest.exists() and latest.stat().st_mtime_ns != before:
                time.sleep(float(rng.uniform(0.0, 1.5)))
                break
            time.sleep(0.05)
        if proc.poll() is not None:
            break  # finished first
        os.killpg(proc.pid, signal.SIGKILL)  # the run and its loader worker
        proc.wait()
        kills += 1
        steps_at_kill.append(torch.load(latest, map_location="cpu", weights_only=False)["global_step"])
    final = run_module("neuraldem", "train", *args, f"hydra.run.dir={run}", f"ckpt_path={latest}", env=env)
    assert final.returncode == 0, final.stdout + final.stderr
    assert kills >= 2 and 0 < steps_at_kill[0] < 20, steps_at_kill  # resumed from the middle of training
    assert_same_training_state(final_state(tmp_path / "ref"), final_state(run))
    assert not list(run.rglob("*.partial"))


@pytest.mark.solver
@pytest.mark.parametrize("written_as", ["BedDataModule", "FluidizedBedDataModule"])
def test_a_killed_bed_training_resumes_exactly(fb_tiny_dataset: Path, tmp_path: Path, written_as: str):
    """The bed's training steps draw (unroll lengths, input noise, supernodes): killed at step 5 and resumed
    from its step-4 checkpoint, it ends with the uninterrupted run's weights; also from a checkpoint that stored
    the data module's place under the class's name before 0.7 (`written_as`)."""
    args = ("experiment=fb_quick", "logger=none", "evaluate=false", "trainer.max_steps=8", "callbacks.progress=null",
            "+callbacks.latest.every_n_train_steps=2", f"data.dataset_dir={fb_tiny_dataset}")
    env = {"NEURALDEM_DATA": str(tmp_path)}
    ref = run_module("neuraldem", "train", *args, f"hydra.run.dir={tmp_path}/ref", env=env)
    assert ref.returncode == 0, ref.stdout + ref.stderr
    run = tmp_path / "killed"
    kill = ("+callbacks.kill._target_=tests.helpers.KillAtStep", "+callbacks.kill.step=5")
    killed = run_module("neuraldem", "train", *args, f"hydra.run.dir={run}", *kill, env=env)
    assert killed.returncode == -signal.SIGKILL
    assert final_state(run)["global_step"] == 4
    ckpt = torch.load(run / "checkpoints" / "latest.ckpt", weights_only=False)
    ckpt[written_as] = ckpt.pop("BedDataModule")
    torch.save(ckpt, run / "checkpoints" / "latest.ckpt")
    resumed = run_module("neuraldem", "train", *args, f"hydra.run.dir={run}",
                         f"ckpt_path={run}/checkpoints/latest.ckpt", env={**env, "NEURALDEM_TEST_NO_KILL": "1"})
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert_same_training_state(final_state(tmp_path / "ref"), final_state(run))
