"""Scalar baselines on hopper datasets: fit the constant or the Gaussian process on training runs, answer test
runs, and score the answers with `score_answers`, the same function that scores the field model.

The baselines see the scene scalars of the model's conditioning without the time `t`: they answer the
practitioner's numbers directly, not fields over time.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from neuraldem.config import checks
from neuraldem.data.manifest import SimRecord
from neuraldem.errors import ConfigError, DataError
from neuraldem.models.scalar_baselines import TARGETS, ConstantBaseline, GaussianProcessBaseline, ScalarBaseline
from neuraldem.scenes.hopper.analysis.scoring import score_answers

BASELINES: dict[str, type[ScalarBaseline]] = {"constant": ConstantBaseline, "gp": GaussianProcessBaseline}
ANSWER_REPEATS = 7  # answer_s is the median of this many one-run predictions


def baseline_inputs(conditioning: list[str]) -> list[str]:
    """The model's conditioning without the time `t`: the scene scalars one answer per run depends on."""
    names = [n for n in checks.names("data.conditioning", list(conditioning)) if n != "t"]
    if not names:
        raise ConfigError(f"data.conditioning={list(conditioning)} has no scene scalar besides t",
                          "the scalar baselines need at least one, e.g. data.conditioning=[t,alpha,mu_s,mu_r]")
    return names


def design_matrix(records: list[SimRecord], inputs: list[str]) -> np.ndarray:
    """(runs, inputs) array of the records' scene scalars; a missing scalar names the run."""
    rows = []
    for rec in records:
        values = rec.conditioning()
        missing = [n for n in inputs if n not in values]
        if missing:
            raise DataError(f"run {rec.sim_id} has no scene scalar {missing[0]!r} (has {sorted(values)})",
                            "macroscopic scalars (theta, repose) need datagen with data.characterization.enabled=true")
        rows.append([float(values[n]) for n in inputs])
    return np.asarray(rows, dtype=np.float64).reshape(len(records), len(inputs))


def target_arrays(records: list[SimRecord]) -> dict[str, np.ndarray]:
    """The stored ground-truth metrics as one array per target; a stored NaN stays NaN (dropped in fit)."""
    for rec in records:
        missing = [t for t in TARGETS if t not in rec.metrics]
        if missing:
            raise DataError(f"run {rec.sim_id} has no stored metric(s) {missing}",
                            "rerun datagen on the dataset to rescore its runs")
    return {t: np.array([float(rec.metrics[t]) for rec in records], dtype=np.float64) for t in TARGETS}


def fit_baseline(kind: str, train: list[SimRecord], inputs: list[str]) -> ScalarBaseline:
    """A baseline of `kind` ('constant' or 'gp') fitted on the training runs."""
    if kind not in BASELINES:
        raise ConfigError(f"unknown scalar baseline {kind!r}", f"choose one of {sorted(BASELINES)}")
    return BASELINES[kind](inputs).fit(design_matrix(train, inputs), target_arrays(train))


def baseline_answers(model: ScalarBaseline, records: list[SimRecord], inputs: list[str],
                     mass_flow_threshold: float = 0.5) -> list[dict[str, Any]]:
    """One answer per record: the means and flow regime, the 95 % interval per target and the extrapolation."""
    if list(inputs) != list(model.inputs):
        raise DataError(f"the {model.name} baseline was fitted on inputs {model.inputs}, not {list(inputs)}",
                        "refit it or ask with the inputs it was fitted on")
    out = []
    for a in model.predict(design_matrix(records, inputs)):
        out.append({**a.as_answer(mass_flow_threshold),
                    "interval": {t: [a.low[t], a.high[t]] for t in TARGETS},
                    "extrapolation": a.extrapolation})
    return out


def coverage(truths: list[dict[str, float]], answers: list[dict[str, Any]]) -> dict[str, float]:
    """Share of runs whose DEM value lies inside the 95 % interval, per target (runs without a value skipped)."""
    out = {}
    for t in TARGETS:
        hits = []
        for truth, a in zip(truths, answers, strict=False):
            value = float(truth.get(t, np.nan))
            if np.isfinite(value):
                lo, hi = a["interval"][t]
                hits.append(lo <= value <= hi)
        out[t] = float(np.mean(hits)) if hits else float("nan")
    return out


def answer_seconds(model: ScalarBaseline, x: np.ndarray, repeats: int = ANSWER_REPEATS) -> float:
    """Median wall time to answer ONE run (what a practitioner waits for per question)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        model.predict(x[:1])
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def score_baseline(kind: str, train: list[SimRecord], test: list[SimRecord], conditioning: list[str],
                   mass_flow_threshold: float = 0.5, truths: list[dict[str, float]] | None = None) -> dict[str, Any]:
    """Fit `kind` on `train`, answer `test`, and score the answers like the field model's (plus cost, coverage)
    against `truths` (default: the test runs' stored metrics)."""
    if not test:
        raise DataError("no test runs to score the scalar baseline on", "use a split with a non-empty test part")
    inputs = baseline_inputs(conditioning)
    t0 = time.perf_counter()
    model = fit_baseline(kind, train, inputs)
    fit_s = time.perf_counter() - t0
    answers = baseline_answers(model, test, inputs, mass_flow_threshold)
    truths = [rec.metrics for rec in test] if truths is None else truths
    return {"method": kind, "inputs": inputs, "n_train": len(train),
            "aggregate": score_answers(truths, answers),
            "answers": [{"sim_id": rec.sim_id, **a} for rec, a in zip(test, answers, strict=False)],
            "n_extrapolated": int(sum(bool(a["extrapolation"]) for a in answers)),
            "fit_s": fit_s, "answer_s": answer_seconds(model, design_matrix(test[:1], inputs)),
            "n_parameters": model.n_parameters, "coverage_95": coverage(truths, answers)}


__all__ = ["BASELINES", "baseline_answers", "baseline_inputs", "coverage", "design_matrix", "fit_baseline",
           "score_baseline", "target_arrays"]
