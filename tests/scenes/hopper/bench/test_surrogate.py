"""The surrogate as the benchmarks load and question it: the right checkpoint for the right scene only."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from neuraldem.bench.choices import pick_record
from neuraldem.data.manifest import Manifest
from neuraldem.errors import DataError
from neuraldem.scenes.hopper.bench.surrogate import (
    answer,
    full_question,
    load_surrogate,
    net_config_of,
    reduced_question,
    surrogate_dataset,
    synthetic_question,
    untrained_surrogate,
)


def test_full_and_reduced_questions(tiny_checkpoint: Path, hopper_tiny_dataset: Path, tmp_path: Path):
    s = load_surrogate(tiny_checkpoint)
    dataset, m = surrogate_dataset(s, hopper_tiny_dataset, tmp_path)
    rec = pick_record(m, "random", None)
    assert rec.sim_id == m.splits["random"]["test"][0]
    q = full_question(m, dataset, rec, s.predictor.norm)
    assert q.times[0] == 0.0 and q.times[-1] == pytest.approx(s.predictor.norm.horizon)
    assert q.points.shape == (m.scene["hopper"]["n_particles"], 3)
    small = reduced_question(q, 20, seed=1)
    assert len(small.points) == 20 and all(any(np.array_equal(p, x) for x in q.points) for p in small.points)
    assert reduced_question(q, 10**6) is q  # more points than particles: the full question
    fields = answer(s, small)
    assert fields.occupancy.shape == (len(q.times), 20) and fields.transport.shape == (len(q.times), 20, 3)
    assert net_config_of(tiny_checkpoint)["n_latent_tokens"] == 8


def test_untrained_surrogate_of_any_token_count():
    s = untrained_surrogate("hopper_tiny", ["t", "alpha", "mu_s", "mu_r"], n_latent_tokens=4)
    q = synthetic_question(s, n_points=7, n_times=3)
    fields = answer(s, q)
    assert fields.residence.shape == (3, 7)
    bigger = untrained_surrogate("hopper_tiny", ["t", "alpha", "mu_s", "mu_r"], n_latent_tokens=16)
    assert bigger.parameters > s.parameters


def test_checkpoint_of_another_kind_is_refused(tmp_path: Path):
    ckpt = tmp_path / "fb.ckpt"
    torch.save({"hyper_parameters": {"metadata": {"kind": "fluidized_bed", "data_name": "fb_tiny"}}}, ckpt)
    with pytest.raises(DataError, match="'fluidized_bed' checkpoint .* needs a hopper model"):
        load_surrogate(ckpt)


def test_checkpoint_of_another_scene_is_refused(tiny_checkpoint: Path, hopper_tiny_dataset: Path, tmp_path: Path):
    other = tmp_path / "other"
    shutil.copytree(hopper_tiny_dataset / "sims", other / "sims")
    shutil.copy2(hopper_tiny_dataset / "manifest.json", other / "manifest.json")
    m = Manifest.load(other)
    m.scene["hopper"]["outlet_diameter"] = 0.05
    m.save(other)
    with pytest.raises(DataError, match=r"scene differs .*hopper\.outlet_diameter"):
        surrogate_dataset(load_surrogate(tiny_checkpoint), other, tmp_path)
