"""Conservative advection of the tagged solid: exact conservation, bounded concentration, no mixing where
nothing moves, transport in the flux direction, and less numerical mixing with flux correction than upwind."""

from __future__ import annotations

import pytest
import torch

from neuraldem.models.modules.conservative_advection import advect_tagged, prior_share, tagged_volume

SPACING = (0.004, 0.006, 0.004)
PRIOR = 1e-3
DT = 0.01


def _state(seed: int, shape=(2, 12, 1, 30), flux_scale: float = 0.2):
    g = torch.Generator().manual_seed(seed)
    alpha = 0.6 * torch.rand(*shape, generator=g, dtype=torch.float64)
    alpha[..., 20:] = 0.0  # an empty freeboard
    beta = alpha * torch.rand(*shape, generator=g, dtype=torch.float64)  # tagged solid per cell
    share = (beta.flatten(1).sum(1) / alpha.flatten(1).sum(1)).view(-1, 1, 1, 1)
    conc = (beta + PRIOR * share) / (alpha + PRIOR)  # as the data's mixing field (dataset/fields.py)
    flux = flux_scale * torch.randn(shape[0], 3, *shape[1:], generator=g, dtype=torch.float64)
    return alpha, conc, flux


@pytest.mark.parametrize("scheme,correction", [("fct", 1.0), ("fct", 0.75), ("upwind", 1.0)])
@pytest.mark.parametrize("flux_scale", [0.05, 0.5, 50.0])  # Courant numbers from ~0.1 to far above 1
def test_tagged_volume_is_conserved_and_concentration_stays_in_range(scheme: str, correction: float,
                                                                    flux_scale: float):
    alpha, conc, flux = _state(0, flux_scale=flux_scale)
    before = tagged_volume(alpha, conc)
    for _ in range(20):
        conc, carried = advect_tagged(alpha, conc, flux, DT, SPACING, scheme=scheme, correction=correction)
        assert conc.min() >= 0.0 and conc.max() <= 1.0
        torch.testing.assert_close(carried.flatten(1).sum(1), alpha.flatten(1).sum(1), rtol=1e-12, atol=0)
        torch.testing.assert_close(tagged_volume(carried, conc), before, rtol=1e-10, atol=1e-12)
        alpha = carried  # keep moving the same solid
        flux = flux.roll(1, dims=-1)


def test_bad_fluxes_and_empty_cells_cannot_leave_the_range():
    alpha, conc, flux = _state(1)
    flux[0, 2, 3, 0, 4] = float("nan")
    flux[1, 0, 5, 0, 5] = float("inf")
    new, carried = advect_tagged(alpha, conc, flux, DT, SPACING)
    assert torch.isfinite(new).all() and new.min() >= 0 and new.max() <= 1
    # where no solid is after the step the concentration is the global share (no 0/0)
    empty = carried == 0
    assert empty.sum() > 50
    torch.testing.assert_close(new[empty], prior_share(alpha, conc).expand_as(new)[empty])


def test_no_flux_changes_nothing_and_a_uniform_bed_stays_uniform():
    alpha, conc, flux = _state(2)
    new, carried = advect_tagged(alpha, conc, torch.zeros_like(flux), DT, SPACING)
    torch.testing.assert_close(new, conc)
    torch.testing.assert_close(carried, alpha)
    uniform = torch.full_like(conc, 0.3)
    new, _ = advect_tagged(alpha, uniform, flux, DT, SPACING)
    torch.testing.assert_close(new, uniform)  # stirring a fully mixed bed cannot unmix or over-mix it


def _column(scheme: str, steps: int, correction: float = 1.0) -> torch.Tensor:
    """A left (c = 0) / right (c = 1) bed moved to the right at 0.1 m/s (Courant 0.25)."""
    alpha = torch.full((1, 40, 1, 1), 0.5, dtype=torch.float64)
    conc = torch.zeros_like(alpha)
    conc[:, 20:] = 1.0
    flux = torch.zeros(1, 3, 40, 1, 1, dtype=torch.float64)
    flux[:, 0] = 0.5 * 0.1
    for _ in range(steps):
        conc, _ = advect_tagged(alpha, conc, flux, DT, SPACING, scheme=scheme, correction=correction)
    return conc[0, :, 0, 0]


def test_transport_goes_with_the_flux_and_flux_correction_mixes_less_than_upwind():
    upwind, fct = _column("upwind", 16), _column("fct", 16)  # 16 x 0.25 = 4 cells to the right
    for profile in (upwind, fct):
        assert profile[:18].max() < 0.05 and profile[28:36].min() > 0.95  # the c = 0 region moved right
        half = int((profile < 0.5).sum())
        assert half == pytest.approx(24, abs=1)  # the interface (c = 0.5) moved from cell 20 to ~24
    partial = _column("fct", 16, correction=0.5)
    width = {name: int(((p > 0.05) & (p < 0.95)).sum())
             for name, p in (("upwind", upwind), ("fct", fct), ("half", partial))}
    assert width["fct"] < width["half"] < width["upwind"], width  # the correction weight sets the mixing


def test_unknown_scheme_is_refused():
    alpha, conc, flux = _state(3)
    with pytest.raises(ValueError, match="unknown advection scheme 'weno'"):
        advect_tagged(alpha, conc, flux, DT, SPACING, scheme="weno")


def _target(alpha: torch.Tensor, seed: int) -> torch.Tensor:
    """Another solid fraction of the same volume per row (a model's next state after the volume projection)."""
    g = torch.Generator().manual_seed(seed)
    other = alpha * (1.0 + 0.3 * torch.rand(alpha.shape, generator=g, dtype=torch.float64))
    return other * (alpha.flatten(1).sum(1) / other.flatten(1).sum(1)).view(-1, 1, 1, 1)


@pytest.mark.parametrize("empty_freeboard", [False, True])
def test_consistent_fluxes_carry_the_solid_to_the_target_and_keep_the_tagged_volume_across_steps(
        empty_freeboard: bool):
    """A flux that disagrees with the next solid fraction: advected as it is, the concentration paired with
    that next field loses or gains tagged solid every step; made consistent, the fluxes carry the solid to it
    and the tagged volume is kept from step to step (synthetic fields, no solver data). With an empty
    freeboard the limiter acts (cells asked to give more than they hold); the settling step closes that gap."""
    alpha, conc, flux = _state(4, flux_scale=0.02)
    if not empty_freeboard:
        alpha = alpha + 0.05  # solid everywhere: the limiter never acts
    before = tagged_volume(alpha, conc)
    raw_alpha, raw_conc = alpha, conc
    for step in range(20):
        target = _target(alpha, step)
        conc, carried = advect_tagged(alpha, conc, flux, DT, SPACING, correction=0.75, target=target)
        torch.testing.assert_close(carried, target, rtol=0, atol=1e-10)
        assert conc.min() >= 0.0 and conc.max() <= 1.0
        torch.testing.assert_close(tagged_volume(target, conc), before, rtol=1e-10, atol=0)
        alpha = target
        raw_target = _target(raw_alpha, step)
        raw_conc, _ = advect_tagged(raw_alpha, raw_conc, flux, DT, SPACING, correction=0.75)
        raw_alpha = raw_target  # the same pairing without the correction
    drift = (tagged_volume(raw_alpha, raw_conc) / before - 1).abs().max()
    assert drift > 1e-3, drift


def test_a_flux_that_already_carries_the_solid_there_is_left_alone():
    from neuraldem.models.modules.conservative_advection import consistent_faces, face_fluxes, net_outflow

    alpha, conc, flux = _state(5, flux_scale=0.005)
    alpha = alpha + 0.05
    target = alpha - net_outflow(face_fluxes(flux), DT, SPACING, alpha)  # exactly where this flux takes it
    assert target.min() > 0
    faces = consistent_faces(alpha, target, face_fluxes(flux), DT, SPACING)
    for a, jf in face_fluxes(flux).items():
        torch.testing.assert_close(faces[a], jf, rtol=0, atol=1e-12)
    with_target, _ = advect_tagged(alpha, conc, flux, DT, SPACING, n_substeps=4, target=target)
    torch.testing.assert_close(with_target, advect_tagged(alpha, conc, flux, DT, SPACING, n_substeps=4)[0],
                               rtol=0, atol=1e-12)
    # a target of another volume: only the part a flux can carry is corrected; the solid volume stays the input's
    _, carried = advect_tagged(alpha, conc, flux, DT, SPACING, target=1.1 * target)
    torch.testing.assert_close(carried.flatten(1).sum(1), alpha.flatten(1).sum(1), rtol=1e-12, atol=0)


@pytest.mark.parametrize("with_target", [False, True])
def test_a_grid_with_faces_on_all_three_axes_conserves_and_commutes_with_swapping_axes(with_target: bool):
    """The per-axis face bookkeeping on a grid with faces along x, y and z (the bed's grid has them on x and z
    only): the tagged volume is kept, c stays in range, the target is reached, and swapping x and z of every
    field (and of the flux components) swaps the result."""
    alpha, conc, flux = _state(6, shape=(1, 5, 4, 6), flux_scale=0.3)
    target = _target(alpha, 6) if with_target else None
    new, carried = advect_tagged(alpha, conc, flux, DT, SPACING, target=target)
    assert new.min() >= 0.0 and new.max() <= 1.0
    torch.testing.assert_close(tagged_volume(carried, new), tagged_volume(alpha, conc), rtol=1e-10, atol=1e-12)
    if with_target:
        torch.testing.assert_close(carried, target, rtol=0, atol=1e-10)

    def swap(x):
        return None if x is None else x.transpose(-3, -1)

    swapped, swapped_carried = advect_tagged(swap(alpha), swap(conc), swap(flux)[:, [2, 1, 0]], DT, SPACING[::-1],
                                             target=swap(target))
    torch.testing.assert_close(swapped, swap(new), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(swapped_carried, swap(carried), rtol=1e-12, atol=1e-12)
