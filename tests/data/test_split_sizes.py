"""How many runs a split needs for a validation and a test part of their own, and the one line datagen prints when
a dataset has fewer."""

from __future__ import annotations

import pytest

from neuraldem.data.splits import random_split, runs_for_own_parts, too_few_warning


@pytest.mark.parametrize(("fractions", "needed"), [
    ({"train": 0.8, "val": 0.1, "test": 0.1}, 10),  # hopper_small: random split of the runs
    ({"train": 0.7, "val": 0.15, "test": 0.15}, 7),  # fb_small: velocities
    ({"train": 0.5, "val": 0.0, "test": 0.5}, 2),  # fb_tiny: no validation part asked
])
def test_the_runs_a_split_needs_follow_from_its_fractions(fractions: dict[str, float], needed: int):
    assert runs_for_own_parts(fractions) == needed
    parts = random_split([f"r{i}" for i in range(needed)], fractions, seed=0)
    for part in ("val", "test"):  # from `needed` runs on, each part's fraction alone gives it a run
        if fractions[part]:
            assert len(parts[part]) >= 1 and fractions[part] * needed >= 1


def test_datagen_says_in_one_line_how_many_runs_would_be_enough():
    fractions = {"train": 0.8, "val": 0.1, "test": 0.1}
    line = too_few_warning("my_hopper", 6, fractions, "runs", "data.splits.random", "n_sims")
    assert line is not None and "\n" not in line
    assert line.startswith("my_hopper: 6 runs are too few for a validation and a test part of their own "
                           "(data.splits.random: val 0.1, test 0.1)")
    assert line.endswith("10 runs would be enough (n_sims=10)")
    assert too_few_warning("my_hopper", 10, fractions, "runs", "data.splits.random", "n_sims") is None
