"""The one checkpoint loader: read once per process, the model it builds is the one Lightning loads, a
changed file is read again, and a file of another kind is refused naming the command that trains one."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
import torch

from neuraldem.errors import DataError
from neuraldem.eval import checkpoints
from neuraldem.eval.checkpoints import checkpoint_metadata, read_checkpoint
from neuraldem.scenes.hopper.analysis.evaluation import load_hopper_checkpoint
from neuraldem.scenes.hopper.surrogate.module import HopperModule


@pytest.fixture
def counted_loads(monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    checkpoints._read.cache_clear()
    calls: list[Path] = []
    real = torch.load

    def counting(path, *args, **kwargs):
        calls.append(Path(path))
        return real(path, *args, **kwargs)

    monkeypatch.setattr(checkpoints.torch, "load", counting)
    return calls


def test_metadata_then_model_reads_the_file_once(tiny_checkpoint: Path, tmp_path: Path, counted_loads: list[Path]):
    ckpt = tmp_path / "a.ckpt"
    shutil.copy(tiny_checkpoint, ckpt)
    assert checkpoint_metadata(ckpt)["kind"] == "hopper"
    load_hopper_checkpoint(ckpt)
    assert len(counted_loads) == 1
    os.utime(ckpt, ns=(1, 1))  # the file changed on disk: read again
    read_checkpoint(ckpt)
    assert len(counted_loads) == 2


def test_the_built_model_is_the_one_lightning_loads(tiny_checkpoint: Path):
    ours = load_hopper_checkpoint(tiny_checkpoint)
    theirs = HopperModule.load_from_checkpoint(tiny_checkpoint).eval()
    a, b = ours.state_dict(), theirs.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert not ours.training and ours.metadata == theirs.metadata
    scalars = torch.rand(2, len(ours.metadata["conditioning"]))
    pos = torch.rand(2, 16, 3)
    with torch.no_grad():
        out_a = ours.net(scalars, {"occupancy": pos})
        out_b = theirs.net(scalars, {"occupancy": pos})
    assert torch.equal(out_a["occupancy"], out_b["occupancy"])


def test_refusals(tiny_checkpoint: Path, tmp_path: Path):
    with pytest.raises(DataError, match="needs a fluidized_bed model: train one with .*experiment=fb"):
        read_checkpoint(tiny_checkpoint).module("fluidized_bed")
    with pytest.raises(DataError, match="does not exist"):
        read_checkpoint(tmp_path / "none.ckpt")
    (tmp_path / "junk.ckpt").write_text("not a checkpoint")
    with pytest.raises(DataError, match="not a readable checkpoint"):
        read_checkpoint(tmp_path / "junk.ckpt")
