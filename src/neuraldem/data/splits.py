"""Train/val/test splits over the usable simulations of a manifest.

- random: shuffled with a seed into fractions (default 80/10/10).
- band: held-out parameter band (paper sec. 4.2 "Generalization"): every simulation with alpha inside
  the alpha band AND theta inside the theta band is test; val is a random fraction of the rest. With no
  theta band given, the theta band covers the same relative width of the observed theta range as the alpha
  band covers of the alpha range, centred on the observed theta range.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from neuraldem.data.manifest import SimRecord
from neuraldem.errors import DataError


def random_split(ids: Sequence[str], fractions: dict[str, float], seed: int) -> dict[str, list[str]]:
    ids = sorted(ids)
    rng = np.random.default_rng(seed)
    order = [ids[i] for i in rng.permutation(len(ids))]
    n = len(order)
    n_val = int(round(fractions.get("val", 0.0) * n))
    n_test = int(round(fractions.get("test", 0.0) * n))
    if n >= 3:  # a part that was asked for is never empty when the dataset allows it
        n_val = max(n_val, 1) if fractions.get("val", 0.0) > 0 else 0
        n_test = max(n_test, 1) if fractions.get("test", 0.0) > 0 else 0
    n_train = n - n_val - n_test
    return {"train": sorted(order[:n_train]), "val": sorted(order[n_train:n_train + n_val]),
            "test": sorted(order[n_train + n_val:])}


def runs_for_own_parts(fractions: dict[str, float]) -> int:
    """The fewest runs (or velocities) for which every asked part besides training gets a whole run of its own
    from its fraction (fraction x runs >= 1), not only the one run `random_split` rounds it up to."""
    return max((math.ceil(1 / f - 1e-9) for k, f in fractions.items() if k != "train" and f > 0), default=1)


def too_few_warning(name: str, n: int, fractions: dict[str, float], unit: str, key: str, setting: str) -> str | None:
    """One line when `n` runs (velocities) are too few for a validation and a test part of their own, naming how
    many would be enough (`runs_for_own_parts`); None when they are enough."""
    need = runs_for_own_parts(fractions)
    if n >= need:
        return None
    parts = ", ".join(f"{k} {f:g}" for k, f in fractions.items() if k != "train" and f > 0)
    return (f"{name}: {n} {unit} are too few for a validation and a test part of their own ({key}: {parts}): "
            f"each gets one {unit[:-1]} by rounding up, the model's trained range is the span of the training "
            f"{unit} alone (less than the ranges asked) and its test {unit[:-1]} may lie outside it; {need} {unit} "
            f"would be enough ({setting}={need})")


def auto_theta_band(thetas: np.ndarray, alpha_band: tuple[float, float],
                    alpha_range: tuple[float, float]) -> tuple[float, float]:
    rel = (alpha_band[1] - alpha_band[0]) / (alpha_range[1] - alpha_range[0])
    lo, hi = float(np.min(thetas)), float(np.max(thetas))
    centre, half = 0.5 * (lo + hi), 0.5 * rel * (hi - lo)
    return centre - half, centre + half


def band_split(records: Sequence[SimRecord], alpha_band: tuple[float, float],
               theta_band: tuple[float, float] | None, val_fraction: float, seed: int) -> dict[str, list[str]]:
    """Test = inside the (alpha, theta) band; the band's theta part is skipped when theta is unknown."""
    def inside(rec: SimRecord) -> bool:
        a = rec.params["alpha"]
        in_alpha = alpha_band[0] <= a <= alpha_band[1]
        if theta_band is None:
            return in_alpha
        theta = rec.macro.get("theta")
        if theta is None:
            raise DataError(f"simulation {rec.sim_id} has no theta: the band split needs characterization")
        return in_alpha and theta_band[0] <= theta <= theta_band[1]

    test = sorted(r.sim_id for r in records if inside(r))
    rest = [r.sim_id for r in records if not inside(r)]
    parts = random_split(rest, {"val": val_fraction, "test": 0.0}, seed)
    return {"train": parts["train"], "val": parts["val"], "test": test}


# ---- cross-validation: every run is tested exactly once (random) or every interior band once (band)
CV_KINDS = ("random", "band")
MIN_TEST_PER_FOLD = 2  # a fold's test part must hold at least this many runs
MIN_REST = 3  # and the runs outside it (training + validation) at least this many


def cv_test_sets(records: Sequence[SimRecord], kind: str, n_folds: int, seed: int,
                 alpha_range: tuple[float, float]) -> list[list[str]]:
    """The test runs of each fold.

    random: the runs shuffled with `seed` and cut into `n_folds` parts of (nearly) equal size.
    band: the alpha range cut into n_folds + 2 equal bands; fold k holds out the (k + 1)-th band, so every
    fold asks the model to fill a gap inside the trained range (the outermost bands would be extrapolation).
    """
    ids = sorted(r.sim_id for r in records)
    if kind == "random":
        order = [ids[i] for i in np.random.default_rng(seed).permutation(len(ids))]
        return [sorted(part) for part in np.array_split(np.array(order, dtype=object), n_folds)]
    if kind != "band":
        raise DataError(f"unknown cross-validation kind {kind!r}; known: {list(CV_KINDS)}")
    edges = np.linspace(alpha_range[0], alpha_range[1], n_folds + 3)
    return [sorted(r.sim_id for r in records if edges[k + 1] <= r.params["alpha"] < edges[k + 2])
            for k in range(n_folds)]


def cv_split(records: Sequence[SimRecord], kind: str, fold: int, n_folds: int, seed: int, val_fraction: float,
             alpha_range: tuple[float, float], dataset: str = "the dataset") -> dict[str, list[str]]:
    """train/val/test of one fold: test from `cv_test_sets`, val a seeded random share of the rest."""
    if not 0 <= fold < n_folds:
        raise DataError(f"cross-validation fold {fold} does not exist: folds are 0 .. {n_folds - 1}")
    tests = cv_test_sets(records, kind, n_folds, seed, alpha_range)
    too_small = [k for k, t in enumerate(tests) if len(t) < MIN_TEST_PER_FOLD]
    n_rest_min = len(records) - max(len(t) for t in tests)
    if too_small or n_rest_min < MIN_REST:
        raise DataError(f"{dataset} has {len(records)} usable runs: too few for {n_folds}-fold {kind} "
                        f"cross-validation (needs >= {MIN_TEST_PER_FOLD} test runs in every fold and >= "
                        f"{MIN_REST} runs outside it); generate more with neuraldem datagen")
    test = tests[fold]
    rest = [r.sim_id for r in records if r.sim_id not in set(test)]
    parts = random_split(rest, {"val": val_fraction, "test": 0.0}, seed + fold)
    return {"train": parts["train"], "val": parts["val"], "test": test}
