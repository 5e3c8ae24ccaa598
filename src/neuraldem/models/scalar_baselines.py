"""Scalar baselines for a scene's answers: the cheapest honest alternatives to a field model.

A practitioner asks a few numbers per run (a hopper's drainage time, residual, outflow, flow regime; a bed's
height, bubble fraction, Lacey index) as a function of the scene scalars. Before a neural field model earns its
cost it has to beat (1) the training mean and (2) a Gaussian process regression on the scene scalars, one per
answer. Both work on plain arrays: `x` is (runs, inputs) in the order of `inputs`, `y` maps each target name
(default: the hopper's `TARGETS`) to one value per run. NaN targets (an outflow rate that could not be
computed) are left out for that target only.

Both answer a mean and a 95 % predictive interval per target, and flag inputs outside the trained range
(an answer there is an extrapolation). `save`/`load` use pickle: load only files you wrote yourself.
"""

from __future__ import annotations

import math
import os
import pickle
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from neuraldem.config import checks
from neuraldem.errors import DataError

TARGETS = ("drainage_t95", "drainage_time", "residual_fraction", "outflow_rate", "mass_flow_index")
# physical range of each answer: means and interval ends are clipped to it
TARGET_RANGE = {"drainage_t95": (0.0, math.inf), "drainage_time": (0.0, math.inf),
                "residual_fraction": (0.0, 1.0), "outflow_rate": (0.0, math.inf), "mass_flow_index": (-1.0, 1.0)}
MIN_RUNS = 3  # below this neither a percentile interval nor a GP length scale means anything
FILE_FORMAT = "neuraldem-scalar-baseline"
FILE_VERSION = 1
Z95 = 1.959964  # two-sided 95 % quantile of the standard normal

B = TypeVar("B", bound="ScalarBaseline")


@dataclass
class ScalarAnswer:
    """One run's answer: mean and 95 % interval per target, and the inputs outside the trained range
    ({name: [value, trained lo, trained hi]}; empty when every input is inside)."""

    mean: dict[str, float]
    low: dict[str, float]
    high: dict[str, float]
    extrapolation: dict[str, list[float]] = field(default_factory=dict)

    def as_answer(self, mass_flow_threshold: float = 0.5) -> dict[str, float]:
        """The answer in the form `score_answers` reads: the means plus the flow regime (1 = mass flow)."""
        return {**self.mean, "mass_flow": float(self.mean["mass_flow_index"] > mass_flow_threshold)}


class ScalarBaseline:
    """Shared checks, extrapolation flags, clipping and file I/O; subclasses fit and predict per target."""

    name = "scalar baseline"

    def __init__(self, inputs: list[str], targets: tuple[str, ...] = TARGETS,
                 target_range: dict[str, tuple[float, float]] | None = None):
        self.inputs = checks.names("data.conditioning", list(inputs))
        self.targets = tuple(targets)
        # physical range of each answer (means and interval ends are clipped to it); the hopper's by default
        self.target_range = dict(TARGET_RANGE if target_range is None else target_range)
        self.lo: np.ndarray | None = None  # trained range of each input
        self.hi: np.ndarray | None = None

    def __setstate__(self, state: dict[str, Any]) -> None:
        # baselines pickled before targets were a parameter answered the hopper's
        state.setdefault("targets", TARGETS)
        state.setdefault("target_range", dict(TARGET_RANGE))
        self.__dict__.update(state)

    # ---- subclass hooks
    def _fit(self, x: np.ndarray, y: dict[str, np.ndarray]) -> None:
        raise NotImplementedError

    def _predict(self, x: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """{target: (mean, low, high)}, each of shape (n,)."""
        raise NotImplementedError

    @property
    def n_parameters(self) -> int:
        raise NotImplementedError

    # ---- public API
    @property
    def fitted(self) -> bool:
        return self.lo is not None

    def fit(self: B, x: np.ndarray, y: dict[str, np.ndarray]) -> B:
        x, y = self._check_training(x, y)
        self.lo, self.hi = x.min(axis=0), x.max(axis=0)
        self._fit(x, y)
        return self

    def predict(self, x: np.ndarray) -> list[ScalarAnswer]:
        x = self._check_inputs(x, "prediction")
        out = self._predict(x)
        for target, (lo, hi) in self.target_range.items():
            if target in out:
                out[target] = tuple(np.clip(a, lo, hi) for a in out[target])
        return [ScalarAnswer(mean={t: float(out[t][0][i]) for t in self.targets},
                             low={t: float(out[t][1][i]) for t in self.targets},
                             high={t: float(out[t][2][i]) for t in self.targets},
                             extrapolation=self.outside_range(row))
                for i, row in enumerate(x)]

    def outside_range(self, row: np.ndarray) -> dict[str, list[float]]:
        """Inputs of one run outside the trained range: {name: [value, lo, hi]} (same rule as the field model)."""
        assert self.lo is not None and self.hi is not None
        out = {}
        for name, v, lo, hi in zip(self.inputs, row, self.lo, self.hi, strict=False):
            if v < lo - 1e-9 * max(1.0, abs(lo)) or v > hi + 1e-9 * max(1.0, abs(hi)):
                out[name] = [float(v), float(lo), float(hi)]
        return out

    def save(self, path: str | Path) -> Path:
        """Pickle the fitted model with a format version and its input names (written atomically)."""
        if not self.fitted:
            raise ValueError(f"the {self.name} baseline is not fitted: call fit(x, y) before save")
        path = Path(path)
        payload = {"format": FILE_FORMAT, "version": FILE_VERSION, "kind": self.name, "inputs": list(self.inputs),
                   "model": self}
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "wb") as f:
            pickle.dump(payload, f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
        return path

    @classmethod
    def load(cls: type[B], path: str | Path) -> B:
        """A model saved by `save`; a missing, damaged or foreign file is a DataError naming the file."""
        path = Path(path)
        if not path.is_file():
            raise DataError(f"scalar baseline file {path} does not exist", "fit the baseline and save it first")
        try:
            with open(path, "rb") as f:
                payload = pickle.load(f)
        except Exception as e:  # a truncated or foreign file fails in many ways, all of them mean "damaged"
            raise DataError(f"scalar baseline file {path} is damaged or not a saved baseline "
                            f"({type(e).__name__})", "fit the baseline and save it again") from None
        if not isinstance(payload, dict) or payload.get("format") != FILE_FORMAT:
            raise DataError(f"{path} is not a saved scalar baseline", "fit the baseline and save it again")
        if payload.get("version") != FILE_VERSION:
            raise DataError(f"scalar baseline file {path} has format version {payload.get('version')!r}, this "
                            f"neuraldem reads version {FILE_VERSION}", "fit the baseline and save it again")
        model = payload.get("model")
        if not isinstance(model, cls) or payload.get("inputs") != model.inputs:
            raise DataError(f"scalar baseline file {path} holds a {payload.get('kind')!r} model with inputs "
                            f"{payload.get('inputs')}, not a {cls.name!r} baseline",
                            "load it with the class of that model")
        return model

    # ---- checks
    def _check_inputs(self, x: np.ndarray, what: str) -> np.ndarray:
        if what == "prediction" and not self.fitted:
            raise ValueError(f"the {self.name} baseline is not fitted: call fit(x, y) with columns {self.inputs} "
                             "before predict")
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != len(self.inputs):
            raise DataError(f"{what} inputs have shape {x.shape}, expected (runs, {len(self.inputs)}) with columns "
                            f"{self.inputs}")
        bad = [name for name, ok in zip(self.inputs, np.isfinite(x).all(axis=0), strict=False) if not ok]
        if bad:
            raise DataError(f"{what} inputs {bad} contain NaN or infinite values")
        return x

    def _check_training(self, x: np.ndarray, y: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        x = self._check_inputs(x, "training")
        n = len(x)
        if n < MIN_RUNS:
            raise DataError(f"the {self.name} baseline got {n} training run(s), it needs at least {MIN_RUNS}",
                            "generate more runs or use a larger training split")
        missing = [t for t in self.targets if t not in y]
        if missing:
            raise DataError(f"training targets {missing} are missing (need {list(self.targets)})")
        out = {}
        for t in self.targets:
            v = np.asarray(y[t], dtype=np.float64)
            if v.shape != (n,):
                raise DataError(f"training target {t} has shape {v.shape}, expected ({n},) (one value per run)")
            n_ok = int(np.isfinite(v).sum())
            if n_ok < MIN_RUNS:
                raise DataError(f"training target {t} has {n_ok} finite value(s) in {n} runs, the {self.name} "
                                f"baseline needs at least {MIN_RUNS}", "generate more runs")
            out[t] = v
        return x, out


class ConstantBaseline(ScalarBaseline):
    """Answers the training mean whatever the inputs; the interval is the training 2.5/97.5 percentiles.
    Any model that does not beat it has learned nothing about the scene parameters."""

    name = "constant"

    def __init__(self, inputs: list[str], targets: tuple[str, ...] = TARGETS,
                 target_range: dict[str, tuple[float, float]] | None = None):
        super().__init__(inputs, targets, target_range)
        self.stats: dict[str, tuple[float, float, float]] = {}  # target -> (mean, p2.5, p97.5)

    def _fit(self, x: np.ndarray, y: dict[str, np.ndarray]) -> None:
        self.stats = {t: (float(np.nanmean(v)), float(np.nanpercentile(v, 2.5)), float(np.nanpercentile(v, 97.5)))
                      for t, v in y.items()}

    def _predict(self, x: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        return {t: tuple(np.full(len(x), s) for s in self.stats[t]) for t in self.targets}

    @property
    def n_parameters(self) -> int:
        return 3 * len(self.stats)


class GaussianProcessBaseline(ScalarBaseline):
    """One scikit-learn GP per target on the inputs scaled to [0, 1] by the training range: a smooth
    interpolant with one length scale per input (an irrelevant input gets a long one) and a noise term
    (DEM answers scatter with the packing). Interval: mean +- 1.96 predictive std (noise included)."""

    name = "gaussian process"

    def __init__(self, inputs: list[str], n_restarts: int = 3, random_state: int = 0,
                 targets: tuple[str, ...] = TARGETS, target_range: dict[str, tuple[float, float]] | None = None):
        super().__init__(inputs, targets, target_range)
        self.n_restarts = checks.positive_int("n_restarts", n_restarts, allow_zero=True)
        self.random_state = random_state
        self.gps: dict[str, Any] = {}

    def _kernel(self) -> Any:
        from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

        # y is standardised (normalize_y), inputs span [0, 1]: a length scale below 0.05 would fit the gaps
        # between a few dozen runs, above 100 the input is irrelevant
        d = len(self.inputs)
        return (ConstantKernel(1.0, (1e-3, 1e3))
                * Matern(length_scale=np.full(d, 0.5), length_scale_bounds=(0.05, 100.0), nu=2.5)
                + WhiteKernel(1e-2, (1e-6, 1.0)))

    def _scale(self, x: np.ndarray) -> np.ndarray:
        assert self.lo is not None and self.hi is not None
        span = np.where(self.hi > self.lo, self.hi - self.lo, 1.0)  # an input constant in training maps to 0
        return (x - self.lo) / span

    def _fit(self, x: np.ndarray, y: dict[str, np.ndarray]) -> None:
        from sklearn.exceptions import ConvergenceWarning
        from sklearn.gaussian_process import GaussianProcessRegressor

        xs = self._scale(x)
        self.gps = {}
        for t, v in y.items():
            ok = np.isfinite(v)
            gp = GaussianProcessRegressor(kernel=self._kernel(), normalize_y=True,
                                          n_restarts_optimizer=self.n_restarts, random_state=self.random_state)
            with warnings.catch_warnings():
                # a hyperparameter at its bound is expected (an irrelevant input, noise-free data), not a failure
                warnings.simplefilter("ignore", ConvergenceWarning)
                self.gps[t] = gp.fit(xs[ok], v[ok])

    def _predict(self, x: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        xs = self._scale(x)
        out = {}
        for t in self.targets:
            mean, std = self.gps[t].predict(xs, return_std=True)
            out[t] = (mean, mean - Z95 * std, mean + Z95 * std)
        return out

    @property
    def n_parameters(self) -> int:
        """Kernel hyperparameters + one weight per training run, per target, + the input scaling."""
        if not self.gps:
            return 0
        per_target = sum(len(gp.kernel_.theta) + len(gp.alpha_) for gp in self.gps.values())
        return per_target + 2 * len(self.inputs)

    def kernels(self) -> dict[str, str]:
        """The fitted kernel of each target (length scales say which inputs matter)."""
        return {t: str(gp.kernel_) for t, gp in self.gps.items()}


@dataclass
class ScalarWhatIf:
    """One what-if answer of a scalar model: mean and 95 % interval per target, inputs outside the trained
    range, and the answer time per row."""

    mean: dict[str, float]
    low: dict[str, float]
    high: dict[str, float]
    extrapolation: dict[str, list[float]]
    seconds: float


def gp_answers(gp: ScalarBaseline, rows: list[dict[str, float]]) -> list[ScalarWhatIf]:
    """A scalar model's answers for many parameter sets at once (a scan), each with its 95 % interval."""
    t0 = time.perf_counter()
    x = np.array([[row[name] for name in gp.inputs] for row in rows], dtype=np.float64)
    answers = gp.predict(x)
    per = (time.perf_counter() - t0) / max(len(rows), 1)
    return [ScalarWhatIf(a.mean, a.low, a.high, a.extrapolation, per) for a in answers]


def matern25(a: np.ndarray, b: np.ndarray, length_scale: np.ndarray) -> np.ndarray:
    """The Matern kernel with nu = 2.5 between the rows of a and b (unit amplitude), as scikit-learn defines it."""
    r = np.sqrt(5.0) * np.sqrt((((a[:, None, :] - b[None, :, :]) / length_scale) ** 2).sum(axis=-1))
    return (1.0 + r + r**2 / 3.0) * np.exp(-r)


ARRAY_FORMAT = "neuraldem-gp-arrays-1"


class ArrayGaussianProcess(ScalarBaseline):
    """A fitted `GaussianProcessBaseline` as plain arrays (training inputs, weights, Cholesky factor, kernel
    hyperparameters per target) that answers with numpy alone: the same means and intervals without importing
    scikit-learn (about a second of a what-if command), stored as .npz (no pickle)."""

    name = "gaussian process"

    def __init__(self, inputs: list[str], arrays: dict[str, np.ndarray]):
        # the targets are the arrays' own ("<target>.x"), in their stored order; the clip range travels with them
        targets = tuple(str(t) for t in arrays.get("targets", np.array(TARGETS)))
        rng = arrays.get("target_range")
        target_range = None if rng is None else {t: (float(lo), float(hi)) for t, (lo, hi) in zip(targets, rng,
                                                                                                   strict=True)}
        super().__init__(inputs, targets, target_range)
        self.arrays = arrays
        self.lo, self.hi = arrays["lo"], arrays["hi"]

    @classmethod
    def from_fitted(cls, gp: GaussianProcessBaseline) -> ArrayGaussianProcess:
        arrays: dict[str, np.ndarray] = {
            "lo": np.asarray(gp.lo), "hi": np.asarray(gp.hi), "targets": np.array(gp.targets),
            "target_range": np.array([gp.target_range.get(t, (-math.inf, math.inf)) for t in gp.targets])}
        for t, g in gp.gps.items():
            k = g.kernel_  # ConstantKernel * Matern(nu=2.5) + WhiteKernel, as GaussianProcessBaseline builds it
            arrays |= {f"{t}.x": g.X_train_, f"{t}.alpha": g.alpha_, f"{t}.L": g.L_,
                       f"{t}.kernel": np.array([k.k1.k1.constant_value, k.k2.noise_level,
                                                float(np.ravel(g._y_train_mean)[0]),
                                                float(np.ravel(g._y_train_std)[0])]),
                       f"{t}.length_scale": np.atleast_1d(k.k1.k2.length_scale).astype(np.float64)}
        return cls(list(gp.inputs), arrays)

    def _scale(self, x: np.ndarray) -> np.ndarray:
        span = np.where(self.hi > self.lo, self.hi - self.lo, 1.0)
        return (x - self.lo) / span

    def _predict(self, x: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        xs = self._scale(x)
        out = {}
        for t in self.targets:
            a = self.arrays
            constant, noise, y_mean, y_std = a[f"{t}.kernel"]
            k_trans = constant * matern25(xs, a[f"{t}.x"], a[f"{t}.length_scale"])
            mean = y_std * (k_trans @ a[f"{t}.alpha"]).ravel() + y_mean
            v = np.linalg.solve(a[f"{t}.L"], k_trans.T)  # L is lower triangular
            var = np.clip(constant + noise - np.einsum("ij,ij->j", v, v), 0.0, None) * y_std**2
            std = np.sqrt(var)
            out[t] = (mean, mean - Z95 * std, mean + Z95 * std)
        return out

    @property
    def n_parameters(self) -> int:
        return int(sum(len(self.arrays[f"{t}.alpha"]) + len(self.arrays[f"{t}.length_scale"]) + 3
                       for t in self.targets) + 2 * len(self.inputs))

    def save_npz(self, path: str | Path) -> Path:
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, format=np.array(ARRAY_FORMAT), inputs=np.array(self.inputs), **self.arrays)
        os.replace(tmp, path)
        return path

    @classmethod
    def load_npz(cls, path: str | Path) -> ArrayGaussianProcess:
        """A model saved by `save_npz`; a missing, damaged or foreign file is a DataError naming the file."""
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except Exception as e:  # a truncated or foreign file fails in many ways, all of them mean "damaged"
            raise DataError(f"GP file {path} is damaged or not a saved GP ({type(e).__name__})",
                            "rebuild it (neuraldem release)") from None
        if str(data.pop("format", "")) != ARRAY_FORMAT:
            raise DataError(f"{path} is not a GP saved by ArrayGaussianProcess.save_npz",
                            "rebuild it (neuraldem release)")
        inputs = [str(n) for n in data.pop("inputs")]
        return cls(inputs, data)


__all__ = ["MIN_RUNS", "TARGETS", "ArrayGaussianProcess", "ConstantBaseline", "GaussianProcessBaseline", "ScalarAnswer",
           "ScalarBaseline", "ScalarWhatIf", "gp_answers"]
