"""The compiled advection sub-steps are the NumPy ones bit for bit: on random beds with and without flux correction, at
Courant numbers far past the sub-step limit, with empty cells, NaN and infinite fluxes, and with the consistent
fluxes of a target; on grids with faces on two and three axes and a batch of several rows. (The compiled
water filling is checked beside its other forms in tests/scenes/fluidized_bed/surrogate/test_autoregressive.py.)"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuraldem.models.modules import compiled
from neuraldem.models.modules.conservative_advection import advect_tagged

from .test_conservative_advection import DT, SPACING, _state, _target

pytestmark = pytest.mark.skipif(not compiled.available(), reason="numba is not installed")


Pair = tuple[tuple[torch.Tensor, ...], tuple[torch.Tensor, ...]]


def _both(monkeypatch: pytest.MonkeyPatch, *args, **kwargs) -> Pair:
    fast = advect_tagged(*args, **kwargs)
    with monkeypatch.context() as m:
        m.setattr(compiled, "available", lambda: False)
        reference = advect_tagged(*args, **kwargs)
    return fast, reference


def _assert_bits(a: tuple[torch.Tensor, ...], b: tuple[torch.Tensor, ...]) -> None:
    for x, y in zip(a, b, strict=True):
        assert x.dtype == y.dtype
        np.testing.assert_array_equal(x.numpy().view(np.int64 if x.dtype == torch.float64 else np.int32),
                                      y.numpy().view(np.int64 if y.dtype == torch.float64 else np.int32))


@pytest.mark.parametrize("scheme,correction", [("fct", 1.0), ("fct", 0.6), ("upwind", 1.0)])
@pytest.mark.parametrize("flux_scale", [0.05, 0.5, 50.0])
@pytest.mark.parametrize("shape", [(2, 12, 1, 30), (1, 5, 4, 6)])
def test_compiled_substeps_equal_numpy_bit_for_bit(monkeypatch, scheme, correction, flux_scale, shape):
    for seed in range(4):
        alpha, conc, flux = _state(seed, shape=shape, flux_scale=flux_scale)
        fast, reference = _both(monkeypatch, alpha, conc, flux, DT, SPACING, scheme=scheme,
                                    correction=correction)
        _assert_bits(fast, reference)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_consistent_fluxes_and_bad_values_equal_numpy_bit_for_bit(monkeypatch, dtype):
    alpha, conc, flux = _state(5)
    flux[0, 2, 3, 0, 4] = float("nan")
    flux[1, 0, 5, 0, 5] = float("inf")
    conc[0, 1, 0, 1] = float("nan")
    target = _target(alpha, 5)
    args = [t.to(dtype) for t in (alpha, conc, flux)]
    fast, reference = _both(monkeypatch, *args, DT, SPACING, target=target.to(dtype))
    _assert_bits(fast, reference)
    assert fast[0].dtype == dtype


def test_the_check_can_fail(monkeypatch):
    """A sub-step count one higher on one side is caught: the comparison reads the last bits."""
    alpha, conc, flux = _state(6)
    fast = advect_tagged(alpha, conc, flux, DT, SPACING, n_substeps=3)
    with monkeypatch.context() as m:
        m.setattr(compiled, "available", lambda: False)
        reference = advect_tagged(alpha, conc, flux, DT, SPACING, n_substeps=4)
    with pytest.raises(AssertionError):
        _assert_bits(fast, reference)
