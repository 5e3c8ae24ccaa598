"""The resumable training order: seeded per epoch, independent of torch's RNG, and a pass that skips k samples
is the tail of the full pass (what a resumed run relies on)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuraldem.data.resumable import Draw, ResumableSampler, sample_rng


def test_a_skipped_pass_is_the_tail_of_the_full_pass_and_only_once():
    s = ResumableSampler(10, seed=4)
    s.set_epoch(3)
    full = list(s)
    s.skip_next(7)
    assert list(s) == full[7:]
    assert list(s) == full  # the skip applies to the next pass only
    assert sorted(d.index for d in full) == list(range(10))  # a permutation
    assert [d.draw for d in full] == list(range(30, 40))  # draw numbers unique over the run


def test_order_depends_on_seed_and_epoch_not_on_torch_rng():
    a, b = ResumableSampler(50, seed=1), ResumableSampler(50, seed=1)
    torch.manual_seed(0)
    first = list(a)
    torch.manual_seed(123)
    assert list(b) == first
    b.set_epoch(1)
    assert [d.index for d in b] != [d.index for d in first]
    assert [d.index for d in ResumableSampler(50, seed=2)] != [d.index for d in first]


def test_weighted_draws_follow_the_weights():
    w = np.array([0.0, 1.0, 3.0])
    s = ResumableSampler(3, seed=0, weights=w)
    counts = np.zeros(3)
    for epoch in range(400):
        s.set_epoch(epoch)
        for d in s:
            counts[d.index] += 1
    assert counts[0] == 0 and counts[2] / counts[1] == pytest.approx(3.0, rel=0.1)


@pytest.mark.parametrize("weights", [np.array([1.0, -1.0]), np.array([0.0, 0.0]), np.array([1.0]),
                                     np.array([np.nan, 1.0])])
def test_bad_weights_are_refused(weights: np.ndarray):
    with pytest.raises(ValueError, match="weights"):
        ResumableSampler(2, seed=0, weights=weights)


def test_sample_randomness_is_a_function_of_seed_and_draw():
    assert np.array_equal(sample_rng(0, 5).random(3), sample_rng(0, 5).random(3))
    assert not np.array_equal(sample_rng(0, 5).random(3), sample_rng(0, 6).random(3))
    assert not np.array_equal(sample_rng(0, 5).random(3), sample_rng(1, 5).random(3))
    assert Draw(2, 9).index == 2


def _batches(sampler: ResumableSampler, size: int) -> list[list[Draw]]:
    draws = list(sampler)
    return [draws[i:i + size] for i in range(0, len(draws) - size + 1, size)]


@pytest.mark.parametrize("n,world,batch", [(23, 2, 4), (24, 3, 6), (10, 4, 8)])
def test_processes_share_out_the_one_process_batches(n: int, world: int, batch: int):
    """Data-parallel: process r takes positions r, r + W, ...; at each step the processes' batches of B / W are
    together the one-process batch B, with its draw numbers (so each sample's randomness is the same)."""
    one = ResumableSampler(n, seed=3)
    one.set_epoch(2)
    shards = [ResumableSampler(n, seed=3, rank=r, world=world) for r in range(world)]
    for s in shards:
        s.set_epoch(2)
    reference = _batches(one, batch)
    per_rank = [_batches(s, batch // world) for s in shards]
    assert all(len(b) == len(reference) for b in per_rank)  # as many steps on every process
    for step, expected in enumerate(reference):
        got = [d for r in range(world) for d in per_rank[r][step]]
        assert sorted(got) == sorted(expected)
        assert per_rank[1][step][0] == expected[1]  # process r's row j is global row r + W j


def test_a_process_resumes_at_its_share_of_the_saved_position():
    s = ResumableSampler(20, seed=1, rank=1, world=2)
    full = list(s)
    s.skip_next(3)  # 3 of this process's samples done
    assert list(s) == full[3:] and len(s) == 10
    with pytest.raises(ValueError, match="rank 2 of 2"):
        ResumableSampler(20, seed=1, rank=2, world=2)
