"""Scalar baselines (constant, Gaussian process) on synthetic data: fast, no dataset and no solver.

The targets are smooth known functions of 3 inputs in [0, 1] with a little noise; held-out points lie inside
the trained range."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neuraldem.errors import DataError
from neuraldem.models.scalar_baselines import TARGETS, ConstantBaseline, GaussianProcessBaseline

INPUTS = ["alpha", "mu_s", "mu_r"]


def truth(x: np.ndarray) -> dict[str, np.ndarray]:
    a, b, c = x.T
    base = 0.5 + 0.3 * np.sin(2.5 * a) + 0.2 * b**2 + 0.05 * c
    return {"drainage_t95": base, "drainage_time": 1.2 * base, "residual_fraction": 0.6 * a * b,
            "outflow_rate": 2.0 - base, "mass_flow_index": np.tanh(3 * (a - 0.5))}


@pytest.fixture(scope="module")
def data() -> dict[str, object]:
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 1, (40, 3))
    y = {k: v + 0.01 * rng.standard_normal(len(x)) for k, v in truth(x).items()}
    x_test = rng.uniform(0.05, 0.95, (60, 3))
    return {"x": x, "y": y, "x_test": x_test, "y_test": truth(x_test)}


@pytest.fixture(scope="module")
def gp(data) -> GaussianProcessBaseline:
    return GaussianProcessBaseline(INPUTS).fit(data["x"], data["y"])


def means(answers, key: str) -> np.ndarray:
    return np.array([a.mean[key] for a in answers])


def test_gp_beats_the_constant_on_held_out_points(gp, data):
    const = ConstantBaseline(INPUTS).fit(data["x"], data["y"])
    pg, pc = gp.predict(data["x_test"]), const.predict(data["x_test"])
    for key in TARGETS:
        err_gp = np.mean(np.abs(means(pg, key) - data["y_test"][key]))
        err_const = np.mean(np.abs(means(pc, key) - data["y_test"][key]))
        assert err_gp < 0.2 * err_const, (key, err_gp, err_const)
    assert gp.name == "gaussian process" and gp.n_parameters > const.n_parameters > 0


def test_gp_intervals_cover_held_out_truths(gp, data):
    answers = gp.predict(data["x_test"])
    for key in TARGETS:
        value = data["y_test"][key]
        low, high = np.array([a.low[key] for a in answers]), np.array([a.high[key] for a in answers])
        assert np.all(low <= high)
        assert np.mean((low <= value) & (value <= high)) >= 0.8, key


def test_answers_are_clipped_to_the_physical_range(gp, data):
    far = np.array([[3.0, -2.0, 0.5]])  # far outside: the GP must not answer a negative time or residual > 1
    a = gp.predict(far)[0]
    assert 0.0 <= a.low["residual_fraction"] <= a.mean["residual_fraction"] <= a.high["residual_fraction"] <= 1.0
    assert min(a.low["drainage_t95"], a.low["drainage_time"], a.low["outflow_rate"]) >= 0.0
    assert -1.0 <= a.low["mass_flow_index"] <= a.high["mass_flow_index"] <= 1.0


def test_extrapolation_names_the_input_and_the_trained_range(gp, data):
    inside, outside = gp.predict(np.array([[0.5, 0.5, 0.5], [0.5, 1.7, 0.5]]))
    assert inside.extrapolation == {}
    lo, hi = data["x"][:, 1].min(), data["x"][:, 1].max()
    assert list(outside.extrapolation) == ["mu_s"]
    assert outside.extrapolation["mu_s"] == pytest.approx([1.7, lo, hi])


def test_as_answer_adds_the_flow_regime(gp):
    a = gp.predict(np.array([[0.9, 0.5, 0.5], [0.1, 0.5, 0.5]]))
    assert set(a[0].as_answer()) == {*TARGETS, "mass_flow"}
    assert a[0].as_answer()["mass_flow"] == 1.0 and a[1].as_answer()["mass_flow"] == 0.0
    assert a[0].as_answer(mass_flow_threshold=1.0)["mass_flow"] == 0.0


def test_constant_answers_the_training_mean(data):
    const = ConstantBaseline(INPUTS).fit(data["x"], data["y"])
    a = const.predict(np.array([[0.1, 0.2, 0.3], [0.9, 0.8, 0.7]]))
    for key in TARGETS:
        assert a[0].mean[key] == a[1].mean[key] == pytest.approx(np.mean(data["y"][key]))
        assert a[0].high[key] == pytest.approx(np.percentile(data["y"][key], 97.5))
    assert const.name == "constant"


def test_nan_targets_are_dropped_for_that_target_only(data):
    y = {k: v.copy() for k, v in data["y"].items()}
    y["outflow_rate"][:5] = np.nan
    const = ConstantBaseline(INPUTS).fit(data["x"], y)
    a = const.predict(data["x"][:1])[0]
    assert a.mean["outflow_rate"] == pytest.approx(np.mean(data["y"]["outflow_rate"][5:]))
    assert a.mean["drainage_t95"] == pytest.approx(np.mean(data["y"]["drainage_t95"]))


@pytest.mark.parametrize("cls", [ConstantBaseline, GaussianProcessBaseline])
def test_save_load_round_trip(cls, data, tmp_path: Path):
    model = cls(INPUTS).fit(data["x"][:12], {k: v[:12] for k, v in data["y"].items()})
    path = model.save(tmp_path / "baseline.pkl")
    loaded = cls.load(path)
    assert loaded.inputs == INPUTS
    assert loaded.predict(data["x_test"][:5]) == model.predict(data["x_test"][:5])


def test_damaged_or_missing_file_is_a_data_error(data, tmp_path: Path):
    path = ConstantBaseline(INPUTS).fit(data["x"], data["y"]).save(tmp_path / "baseline.pkl")
    path.write_bytes(path.read_bytes()[:40])
    with pytest.raises(DataError, match="baseline.pkl") as e:
        ConstantBaseline.load(path)
    assert "\n" not in str(e.value)
    with pytest.raises(DataError, match="missing.pkl"):
        ConstantBaseline.load(tmp_path / "missing.pkl")
    with pytest.raises(DataError, match="constant"):  # a file of another kind of baseline
        GaussianProcessBaseline.load(ConstantBaseline(INPUTS).fit(data["x"], data["y"]).save(tmp_path / "c.pkl"))


@pytest.mark.parametrize("cls", [ConstantBaseline, GaussianProcessBaseline])
def test_fewer_than_three_runs_is_a_data_error(cls, data):
    with pytest.raises(DataError, match="2 training run.*at least 3"):
        cls(INPUTS).fit(data["x"][:2], {k: v[:2] for k, v in data["y"].items()})


def test_predict_before_fit_or_with_wrong_columns_names_the_inputs(data):
    with pytest.raises(ValueError, match="not fitted.*alpha"):
        ConstantBaseline(INPUTS).predict(data["x"])
    const = ConstantBaseline(INPUTS).fit(data["x"], data["y"])
    with pytest.raises(DataError, match=r"\['alpha', 'mu_s', 'mu_r'\]"):
        const.predict(data["x"][:, :2])


def test_the_array_gp_answers_as_the_fitted_one_without_scikit_learn(gp, data, tmp_path: Path):
    """The shipped form of the GP (arrays, numpy only) gives scikit-learn's means and intervals, NaN targets and
    extrapolation flags included, and survives its file round trip. (Synthetic targets: a unit test.)"""
    import subprocess
    import sys

    from neuraldem.models.scalar_baselines import ArrayGaussianProcess

    x = np.vstack([data["x_test"], [[1.3, 0.5, 0.5]]])  # one point outside the trained range
    path = ArrayGaussianProcess.from_fitted(gp).save_npz(tmp_path / "gp.npz")
    arrays = ArrayGaussianProcess.load_npz(path)
    for a, b in zip(gp.predict(x), arrays.predict(x), strict=True):
        for part in ("mean", "low", "high"):
            for t in TARGETS:
                assert getattr(b, part)[t] == pytest.approx(getattr(a, part)[t], rel=1e-9, abs=1e-12)
        assert a.extrapolation == b.extrapolation
    code = ("import sys; from neuraldem.models.scalar_baselines import ArrayGaussianProcess as G; "
            f"G.load_npz({str(path)!r}).predict([[0.5, 0.5, 0.5]]); print('sklearn' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() \
        == "False"


def test_a_damaged_array_gp_file_is_a_data_error(gp, tmp_path: Path):
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess

    path = tmp_path / "gp.npz"
    path.write_bytes(b"not a zip")
    with pytest.raises(DataError, match="gp.npz is damaged"):
        ArrayGaussianProcess.load_npz(path)


def test_a_scene_of_its_own_targets_fits_clips_and_survives_the_array_form(tmp_path):
    """The bed's answers are other targets than the hopper's: the GP and its numpy form answer them,
    clipped to their own physical ranges."""
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess

    rng = np.random.default_rng(0)
    x = rng.uniform(1.2, 2.2, size=(12, 1))
    y = {"height": 0.02 + 0.01 * x[:, 0], "share": np.clip(0.3 * (x[:, 0] - 1.2), 0, 1)}
    ranges = {"height": (0.0, np.inf), "share": (0.0, 1.0)}
    gp = GaussianProcessBaseline(["v"], n_restarts=0, targets=("height", "share"), target_range=ranges).fit(x, y)
    arrays = ArrayGaussianProcess.from_fitted(gp)
    back = ArrayGaussianProcess.load_npz(arrays.save_npz(tmp_path / "gp.npz"))
    assert back.targets == ("height", "share") and back.target_range == ranges
    a, b = gp.predict([[1.7], [5.0]]), back.predict([[1.7], [5.0]])
    assert a[0].mean == pytest.approx(b[0].mean, rel=1e-9) and set(a[0].mean) == {"height", "share"}
    assert 0.0 <= b[1].high["share"] <= 1.0 and b[1].extrapolation == {"v": [5.0, gp.lo[0], gp.hi[0]]}
    with pytest.raises(DataError, match=r"training targets \['share'\] are missing"):
        GaussianProcessBaseline(["v"], targets=("height", "share")).fit(x, {"height": y["height"]})
