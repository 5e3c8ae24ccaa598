"""Re-sampling particles from a solid-fraction field: the density follows the field, nothing else; the volume
projection reaches its volume under the cap."""

from __future__ import annotations

import pytest
import torch

from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import sample_positions


def _cells(pos: torch.Tensor, shape: tuple[int, int, int]) -> torch.Tensor:
    ijk = (pos * torch.tensor(shape)).floor().long()
    return (ijk[..., 0] * shape[1] + ijk[..., 1]) * shape[2] + ijk[..., 2]


def test_samples_fall_where_the_solid_is_in_proportion():
    shape = (4, 1, 5)
    alpha = torch.zeros(2, *shape)
    alpha[0, 1, 0, 2] = 0.5  # sample 0: one cell
    alpha[1, 0, 0, 0], alpha[1, 3, 0, 4] = 0.1, 0.3  # sample 1: two cells, 1 : 3
    alpha[1, 2, 0, 1] = -0.2  # negative = empty
    g = torch.Generator().manual_seed(0)
    pos = sample_positions(alpha, 20000, g)
    assert pos.shape == (2, 20000, 3) and pos.min() >= 0 and pos.max() < 1
    cells = _cells(pos, shape)
    assert torch.all(cells[0] == 1 * 5 + 2)
    counts = torch.bincount(cells[1], minlength=20)
    assert counts.sum() == counts[0] + counts[3 * 5 + 4]
    assert 0.72 < counts[19] / 20000 < 0.78
    # uniform inside the cell
    inside = pos[0] * torch.tensor(shape) - torch.tensor([1.0, 0.0, 2.0])
    assert torch.allclose(inside.mean(0), torch.full((3,), 0.5), atol=0.02)


def test_empty_or_non_finite_fields_do_not_crash():
    alpha = torch.full((1, 2, 1, 2), float("nan"))
    alpha[0, 1, 0, 1] = 0.4
    cells = _cells(sample_positions(alpha, 500, torch.Generator().manual_seed(1)), (2, 1, 2))
    assert torch.all(cells == 3)
    pos = sample_positions(torch.zeros(1, 2, 1, 2), 400, torch.Generator().manual_seed(1))  # no solid: uniform
    assert len(torch.unique(_cells(pos, (2, 1, 2)))) == 4


def test_volume_projection_reaches_the_volume_without_passing_the_cap():
    """Random heavy-tailed solid-fraction fields (synthetic, no solver data), with volumes from well below what
    their over-cap cells alone hold to near n * cap: the projection ends at the target volume to round-off with
    no cell above the cap and none below 0, and equals the exact water-filling answer min(s a, cap) with the one
    s that fills the volume (found by bisection)."""
    from types import SimpleNamespace

    import numpy as np

    from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import SOLID_FRACTION_CHANNEL, project_volume

    cap, n = 0.72, 200
    norm = SimpleNamespace(mean={"solid_fraction": [0.1]}, std={"solid_fraction": [0.2]}, solid_fraction_max=cap)
    rng = np.random.default_rng(0)
    over_full = 0
    for _ in range(40):
        a = np.exp(rng.normal(0.0, rng.uniform(0.5, 3.0), n)) * 0.05
        held = cap * (a >= cap).sum()
        # every other field: less than its over-cap cells alone hold (the case a fixed "cells over the cap hold
        # it" rule gets wrong), where it has any
        target_volume = held * rng.uniform(0.2, 0.95) if _ % 2 and held > 1 else cap * n * rng.uniform(0.02, 0.9)
        over_full += cap * (a >= cap).sum() > target_volume  # the over-cap cells alone hold too much
        fluid = torch.zeros(1, n, 4, dtype=torch.float64)
        fluid[0, :, SOLID_FRACTION_CHANNEL] = torch.from_numpy((a - 0.1) / 0.2)
        target = torch.tensor([target_volume], dtype=torch.float64)
        alpha = project_volume(fluid, norm, target)[0, :, SOLID_FRACTION_CHANNEL] * 0.2 + 0.1
        assert float(alpha.max()) <= cap + 1e-12 and float(alpha.min()) >= -1e-12
        assert float(alpha.sum()) == pytest.approx(target_volume, rel=1e-9)
        lo, hi = 0.0, cap / a.min()
        for _ in range(200):
            s = 0.5 * (lo + hi)
            lo, hi = (s, hi) if np.minimum(s * a, cap).sum() < target_volume else (lo, s)
        np.testing.assert_allclose(alpha.numpy(), np.minimum(lo * a, cap), atol=1e-9)
    assert over_full >= 10


def test_volume_projection_of_a_field_that_overfills_its_dense_cells():
    """A model's step that piles the bed into 60 cells at up to 1.4 (the rollout of the shipped bed model at
    1.78 m/s, step 93, in miniature): the cells over the cap hold more than the volume, so they must come down
    too. The old projection held them at the cap and came out 2 % over; the rollout then rescaled every cell,
    the capped ones past the cap."""
    from types import SimpleNamespace

    from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import SOLID_FRACTION_CHANNEL, project_volume

    cap = 0.74
    norm = SimpleNamespace(mean={"solid_fraction": [0.0]}, std={"solid_fraction": [1.0]}, solid_fraction_max=cap)
    fluid = torch.zeros(2, 360, 4)
    fluid[:, :60, SOLID_FRACTION_CHANNEL] = torch.linspace(0.75, 1.4, 60)
    fluid[:, 60:100, SOLID_FRACTION_CHANNEL] = 0.3
    volume = torch.tensor([43.6, 12.0], dtype=torch.float64)
    alpha = project_volume(fluid, norm, volume)[..., SOLID_FRACTION_CHANNEL]
    torch.testing.assert_close(alpha.double().sum(1), volume, rtol=1e-6, atol=0)
    assert float(alpha.max()) <= cap + 1e-7 and float(alpha.min()) >= 0
    assert torch.all(alpha[1, :60] < cap)  # 12 cell-volumes cannot keep 60 cells at the cap
    # no solid outside the capped cells: the rest is spread evenly over the empty ones
    lone = torch.full((1, 10, 4), -1.0)
    lone[0, 0, SOLID_FRACTION_CHANNEL] = 5.0
    alpha = project_volume(lone, norm, torch.tensor([2.0], dtype=torch.float64))[0, :, SOLID_FRACTION_CHANNEL]
    assert float(alpha[0]) == pytest.approx(cap) and float(alpha.sum()) == pytest.approx(2.0, rel=1e-6)


@pytest.mark.parametrize("jit", [True, False])
def test_volume_projection_without_a_gradient_is_the_differentiable_ones_bit_for_bit(monkeypatch, jit: bool):
    """A rollout step fills in NumPy, or its Numba-compiled form (no gradient to keep); training in torch. Random
    fields, float32 and float64, ties at the cap, volumes from far below to past what the cap allows (the
    fallback rows): equal to the last bit."""
    from neuraldem.models.modules import compiled
    from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import _water_fill_numpy, water_fill

    if jit and not compiled.available():
        pytest.skip("numba is not installed")
    monkeypatch.setattr(compiled, "available", lambda: jit)

    g = torch.Generator().manual_seed(0)
    cap, numpy_rows = 0.72, 0
    for t in range(600):
        rows, n = 1 + t % 3, (360, 50, 7)[t % 3]
        alpha = torch.rand(rows, n, generator=g, dtype=torch.float64) * (0.9 if t % 2 else 0.5)
        alpha[torch.rand(rows, n, generator=g) < 0.3] = 0.0
        if t % 5 == 0:
            alpha[:, :10] = cap
        alpha = alpha.float() if t % 4 else alpha
        volume = alpha.double().sum(1) * (0.5 + 1.2 * torch.rand(rows, generator=g, dtype=torch.float64))
        with torch.no_grad():
            fast = water_fill(alpha, volume, cap)
        exact = water_fill(alpha.clone().requires_grad_(True), volume, cap).detach()
        assert fast.dtype == exact.dtype and torch.equal(fast, exact), t
        numpy_rows += _water_fill_numpy(alpha.double().numpy(), volume.reshape(-1, 1).numpy(), cap) is not None
    assert 300 < numpy_rows < 600  # both the NumPy fill and the torch fallback were compared


def test_a_projection_first_made_in_a_rollout_step_still_trains():
    """The normaliser's tensors are made once per values; the first may come from a rollout step in inference
    mode, and a later training step must still backpropagate through the projection."""
    from types import SimpleNamespace

    from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import _stat_tensors, project_volume

    _stat_tensors.cache_clear()
    norm = SimpleNamespace(mean={"solid_fraction": [0.25]}, std={"solid_fraction": [0.5]}, solid_fraction_max=0.7)
    fluid = torch.rand(1, 12, 4, generator=torch.Generator().manual_seed(3))
    volume = torch.tensor([1.5], dtype=torch.float64)
    with torch.inference_mode():
        first = project_volume(fluid, norm, volume)
    trained = fluid.clone().requires_grad_(True)
    again = project_volume(trained, norm, volume)
    again.sum().backward()
    assert trained.grad is not None and torch.equal(first, again.detach())


def test_sampled_cells_unravel_as_torch_does():
    from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import _unravel

    cells = torch.randint(0, 360, (2, 500), generator=torch.Generator().manual_seed(2))
    for shape in ((12, 1, 30), (6, 2, 30), (360,)):
        assert torch.equal(_unravel(cells, shape), torch.stack(torch.unravel_index(cells, shape), dim=-1))


def test_continuity_residual_is_zero_exactly_when_the_flux_carries_the_solid():
    """Synthetic fields (no solver data): a next solid fraction made by moving the input with a given flux
    through the cell faces has no residual; the same flux against another next field (same volume) has one,
    in units of the RMS one-step change, and its gradient reaches the flux only."""
    from types import SimpleNamespace

    from neuraldem.models.modules.conservative_advection import face_fluxes, net_outflow
    from neuraldem.models.multi_branch_operator import OperatorInputs
    from neuraldem.scenes.fluidized_bed.surrogate.autoregressive import continuity_residual

    shape, dt, rms = (6, 1, 8), 0.01, 0.02
    norm = SimpleNamespace(mean={"solid_fraction": [0.2], "solids_flux": [0.0, 0.0, 0.01]},
                           std={"solid_fraction": [0.25], "solids_flux": [0.05, 0.05, 0.08]},
                           step_rms={"solid_fraction": [rms]}, dt=dt, box_lo=[0.0, 0.0, 0.0],
                           box_hi=[0.024, 0.006, 0.064], grid_shape=list(shape))
    g = torch.Generator().manual_seed(0)
    alpha_in = 0.3 * torch.rand(2, *shape, generator=g, dtype=torch.float64)
    flux = 0.02 * torch.randn(2, 3, *shape, generator=g, dtype=torch.float64)
    flux[:, 1] = 0.0
    spacing = [0.004, 0.006, 0.008]
    alpha_next = alpha_in - net_outflow(face_fluxes(flux), dt, spacing, alpha_in)

    def model_units(alpha, j):
        a = (alpha - 0.2) / 0.25
        f = (j - torch.tensor([0.0, 0.0, 0.01], dtype=j.dtype).reshape(1, 3, 1, 1, 1)) / \
            torch.tensor([0.05, 0.05, 0.08], dtype=j.dtype).reshape(1, 3, 1, 1, 1)
        return a, f

    a_in, _ = model_units(alpha_in, flux)
    a_next, f = model_units(alpha_next, flux)
    grid = torch.zeros(2, 7, *shape, dtype=torch.float64)
    grid[:, 3] = a_in
    x = OperatorInputs(particle_pos=torch.zeros(2, 1, 3), particle_features=torch.zeros(2, 1, 3), grid=grid,
                       mixing_grid=torch.zeros(2, 1, *shape), scalars=torch.zeros(2, 1))
    fluid = torch.zeros(2, 7, *shape, dtype=torch.float64)
    fluid[:, 3], fluid[:, 4:7] = a_next, f
    fluid = fluid.flatten(2).transpose(1, 2)
    r = continuity_residual(x, fluid, norm)
    assert r.shape == (2, 48) and r.abs().max() < 1e-9
    # another next field of the same volume: the residual is its difference, in units of the RMS change
    bump = torch.zeros(2, *shape, dtype=torch.float64)
    bump[:, 2, 0, 3], bump[:, 3, 0, 3] = 0.01, -0.01
    other = fluid.clone().requires_grad_(True)
    with torch.no_grad():
        other[..., 3] += (bump / 0.25).reshape(2, -1)
    r = continuity_residual(x, other, norm)
    torch.testing.assert_close(r, -bump.reshape(2, -1) / rms)
    r.square().sum().backward()
    assert other.grad[..., 3].abs().sum() == 0 and other.grad[..., [4, 6]].abs().sum() > 0  # the flux only
