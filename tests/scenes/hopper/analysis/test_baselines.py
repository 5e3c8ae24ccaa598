"""Scalar baselines on the real tiny LIGGGHTS hopper dataset: fit on all but 2 runs, score the 2 held out."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from neuraldem.data.manifest import Manifest
from neuraldem.errors import ConfigError, DataError
from neuraldem.models.scalar_baselines import TARGETS
from neuraldem.scenes.hopper.analysis.baselines import baseline_inputs, fit_baseline, score_baseline
from neuraldem.scenes.hopper.analysis.metrics import SCALARS
from neuraldem.scenes.hopper.analysis.scoring import score_answers

pytestmark = pytest.mark.solver

CONDITIONING = ["t", "alpha", "mu_s", "mu_r"]


@pytest.fixture(scope="module")
def runs(hopper_tiny_dataset: Path):
    return Manifest.load(hopper_tiny_dataset).usable()


def test_targets_are_the_hopper_scalars():
    assert TARGETS == SCALARS


def test_baseline_inputs_drop_time():
    assert baseline_inputs(CONDITIONING) == ["alpha", "mu_s", "mu_r"]
    with pytest.raises(ConfigError, match="besides t"):
        baseline_inputs(["t"])


@pytest.mark.parametrize("kind", ["constant", "gp"])
def test_score_baseline_on_held_out_runs(kind, runs):
    train, test = runs[:-2], runs[-2:]
    out = score_baseline(kind, train, test, CONDITIONING)
    expected = score_answers([r.metrics for r in test], [r.metrics for r in test])
    assert set(out["aggregate"]) == set(expected)
    assert out["aggregate"]["n_sims"] == 2
    for key in ("drainage_t95_mae_s", "drainage_t95_pct_of_mean", "drainage_mae_s", "drainage_mae_pct_of_mean"):
        assert np.isfinite(out["aggregate"][key]), key
    assert out["method"] == kind and out["inputs"] == ["alpha", "mu_s", "mu_r"]
    assert [a["sim_id"] for a in out["answers"]] == [r.sim_id for r in test]
    for a in out["answers"]:
        assert set(a["interval"]) == set(TARGETS) and a["mass_flow"] in (0.0, 1.0)
        assert all(lo <= a[t] <= hi for t, (lo, hi) in a["interval"].items())
    assert out["fit_s"] > 0 and 0 < out["answer_s"] < out["fit_s"] + 1.0
    assert set(out["coverage_95"]) == set(TARGETS)
    assert all(0.0 <= c <= 1.0 for c in out["coverage_95"].values())


def test_unknown_kind_lists_the_valid_ones(runs):
    with pytest.raises(ConfigError, match="constant.*gp"):
        fit_baseline("forest", runs, ["alpha"])


def test_missing_input_names_the_run(runs):
    train = list(runs)
    train[1] = replace(train[1], macro={k: v for k, v in train[1].macro.items() if k != "theta"})
    with pytest.raises(DataError, match=f"{train[1].sim_id}.*theta"):
        fit_baseline("gp", train, ["alpha", "theta"])
