"""Conservative (flux-form) advection of a tagged solid fraction by a solids flux field, on a regular grid.

Why: the mixing concentration c (share of group-B solid in a cell) only changes when solid moves. Re-predicting
c absolutely every step lets a network mix the bed in a few steps (a 10 % shrinkage towards the mean share
per step is invisible in a one-step loss); transporting the tagged volume beta = alpha * c with the solid's own
fluxes cannot over-mix beyond the scheme's numerical diffusion, conserves the tagged volume exactly and keeps
c inside [0, 1] by construction.

Scheme (first-order donor cell, one sub-step shown): on every interior face the solid volume that crosses in a
sub-step is F = |j_f| dt / dx (cell-volume fraction; j_f = the face average of the solids flux alpha * u_s
[m/s] along the face normal), taken from the upwind (donor) cell. A cell never gives more than it holds
(outflows scaled down to alpha). The tagged volume moves with the same fluxes times the donor's c. Then

    alpha' = alpha_stay + sum F_in,   beta' = alpha_stay c + sum F_in c_donor,   alpha_stay = alpha - sum F_out

so c' = beta' / alpha' is a convex combination of the c values around (inside [0, 1] if they are), and sum
beta' = sum beta to round-off (walls are closed: no flux through the box faces). Where there is (almost) no
solid, c' tends to the global share p_B through the same prior as the data's mixing field
(c = (beta + a0 p_B) / (alpha + a0), `neuraldem.scenes.fluidized_bed.dataset.fields`). Sub-steps keep the
Courant number <= 0.5.

Consistent fluxes (`target`): the step's concentration is paired with the next solid fraction of whoever made the
fluxes (CFD-DEM's kernel field, a model's projected prediction). When the fluxes do not carry the solid there
(a model's flux and solid fraction are two outputs, and they disagree), the tagged volume is not conserved from
step to step: a cell the fluxes left empty but the model fills gets the global share, which is mixing. Given
`target`, the face fluxes first get the smallest gradient correction j - grad(psi) whose divergence carries the
solid fraction to `target` (a Neumann Poisson problem, solved exactly with a cosine transform; solvable when both
hold the same volume, as the volume projection guarantees).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np
import scipy.fft
import torch

DEFAULT_PRIOR = 1e-3
MAX_COURANT = 0.5
MAX_SUBSTEPS = 16
COURANT_FLOOR = 0.05  # solid fraction below which a cell's speed does not set the sub-steps (see `substeps`)


def _face_flux(j: torch.Tensor, axis: int) -> torch.Tensor:
    """Face average of flux component j (B, nx, ny, nz) on the interior faces normal to `axis`."""
    n = j.shape[axis]
    return 0.5 * (j.narrow(axis, 0, n - 1) + j.narrow(axis, 1, n - 1))


def substeps(flux: torch.Tensor, dt: float, spacing: Sequence[float], solid_fraction: torch.Tensor) -> int:
    """Sub-steps that keep the largest per-cell Courant number (|u_s| dt / dx summed over axes) <= 0.5 in the
    bed. Nearly empty cells (solid fraction < 0.05) count with 0.05: a model's small flux there means a huge
    speed of almost nothing, and the limiter already keeps a cell from giving more than it holds (without the
    floor a model's rollout took the maximum 16 sub-steps every step, 2x the model's own cost)."""
    speed = flux.abs() / solid_fraction.clamp(min=COURANT_FLOOR).unsqueeze(1)  # (B, 3, ...) |u_s| [m/s]
    courant = sum(speed[:, a] * dt / spacing[a] for a in range(3))
    worst = float(courant.max()) if courant.numel() else 0.0
    if not math.isfinite(worst):
        return 1
    return int(min(MAX_SUBSTEPS, max(1, math.ceil(worst / MAX_COURANT))))


def face_fluxes(flux: torch.Tensor) -> dict[int, torch.Tensor]:
    """Face averages (m/s) of a cell-centred flux (B, 3, nx, ny, nz) on the interior faces of every axis with
    more than one cell: axis a -> (B, ...) with n_a - 1 faces along a, >0 from the lower cell to the upper."""
    return {a: _face_flux(flux[:, a], a + 1) for a in range(3) if flux.shape[a + 2] > 1}


def net_outflow(faces: dict[int, torch.Tensor], dt: float, spacing: Sequence[float],
                like: torch.Tensor) -> torch.Tensor:
    """(B, nx, ny, nz) solid fraction each cell loses over `dt` through the faces (signed, no limiter)."""
    out = torch.zeros_like(like)
    for a, jf in faces.items():
        t = jf * (dt / spacing[a])
        m = t.shape[a + 1]
        out.narrow(a + 1, 0, m).add_(t)
        out.narrow(a + 1, 1, m).sub_(t)
    return out


def _neumann_eigenvalues(shape: Sequence[int], spacing: Sequence[float]) -> np.ndarray:
    """Eigenvalues (<= 0) of the cell-centred Neumann Laplacian in the DCT-II basis (a fresh copy: the caller
    may change it; computed once per grid, as a rollout asks every step)."""
    return _eigenvalues(tuple(int(n) for n in shape), tuple(float(h) for h in spacing)).copy()


@functools.lru_cache(maxsize=16)
def _eigenvalues(shape: tuple[int, ...], spacing: tuple[float, ...]) -> np.ndarray:
    lam = np.zeros(tuple(shape))
    for a, n in enumerate(shape):
        k = np.arange(n).reshape([-1 if b == a else 1 for b in range(len(shape))])
        lam = lam + (2.0 * np.cos(np.pi * k / n) - 2.0) / spacing[a] ** 2
    return lam


def consistent_faces(solid_fraction: torch.Tensor, target: torch.Tensor, faces: dict[int, torch.Tensor],
                     dt: float, spacing: Sequence[float]) -> dict[int, torch.Tensor]:
    """The face fluxes plus the smallest gradient correction, -grad(psi), that makes their divergence carry
    `solid_fraction` to `target` over `dt` (module docstring). Lap(psi) = -(alpha - target - net outflow) / dt
    with closed walls; the part of the mismatch with a nonzero mean (unequal volumes) cannot be carried and
    is left out."""
    mismatch = solid_fraction - target - net_outflow(faces, dt, spacing, solid_fraction)
    axes = (1, 2, 3)
    lam = _neumann_eigenvalues(solid_fraction.shape[1:], spacing)
    lam[(0,) * lam.ndim] = 1.0  # the mean: no correction can move it
    rhs = scipy.fft.dctn((-mismatch / dt).detach().cpu().numpy(), type=2, axes=axes, norm="ortho") / lam
    rhs[(slice(None),) + (0,) * lam.ndim] = 0.0
    psi = torch.from_numpy(scipy.fft.idctn(rhs, type=2, axes=axes, norm="ortho")).to(solid_fraction)
    out = {}
    for a, jf in faces.items():
        m = jf.shape[a + 1]
        out[a] = jf - (psi.narrow(a + 1, 1, m) - psi.narrow(a + 1, 0, m)) / spacing[a]
    return out


def _cell_speed_flux(faces: dict[int, torch.Tensor], like: torch.Tensor) -> torch.Tensor:
    """(B, 3, nx, ny, nz) per-axis cell flux magnitude: the mean |face flux| of its two faces (0 at walls)."""
    out = torch.zeros((like.shape[0], 3, *like.shape[1:]), dtype=like.dtype, device=like.device)
    for a, jf in faces.items():
        m = jf.shape[a + 1]
        out[:, a].narrow(a + 1, 0, m).add_(0.5 * jf.abs())
        out[:, a].narrow(a + 1, 1, m).add_(0.5 * jf.abs())
    return out


def advect_tagged(solid_fraction: torch.Tensor, concentration: torch.Tensor, flux: torch.Tensor, dt: float,
                  spacing: Sequence[float], prior: float = DEFAULT_PRIOR, n_substeps: int | None = None,
                  scheme: str = "fct", correction: float = 1.0,
                  target: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Move the tagged solid over one step of `dt` seconds.

    solid_fraction (B, nx, ny, nz) >= 0 and concentration (B, nx, ny, nz) in [0, 1] at the start of the step;
    flux (B, 3, nx, ny, nz): solids flux alpha * u_s [m/s] over the step; spacing: cell sizes [m].
    scheme: "upwind" (donor cell: bounded, but its numerical diffusion mixes a bed several times too fast) or
    "fct" (flux-corrected transport: the central face concentration where the limiter allows it, upwind where
    it would leave the range of the neighbours; bounded and conservative as well). `correction` in [0, 1] scales
    the flux correction before limiting: 1 = full FCT, 0 = upwind; in between keeps part of the upwind
    scheme's numerical mixing, which stands in for the sub-cell dispersion of the particles (calibrated on
    training trajectories: `neuraldem.scenes.fluidized_bed.analysis.advection_oracle`).
    target (B, nx, ny, nz): the solid fraction at the end of the step; the fluxes are made consistent with it
    first (`consistent_faces`), and what the limiter kept them from carrying is settled at the end (`_settle`),
    so the carried solid fraction is the target and the tagged volume is kept (both volumes equal).
    Returns (concentration after the step, solid fraction the fluxes carried there). Non-finite fluxes count
    as zero (a diverging model is caught by the rollout's checks, not here)."""
    if scheme not in SCHEMES:
        raise ValueError(f"unknown advection scheme {scheme!r}; known: {list(SCHEMES)}")
    if not 0.0 <= correction <= 1.0:
        raise ValueError(f"advection correction {correction} outside [0, 1]")
    alpha = solid_fraction.double().clamp(min=0.0)
    conc = torch.nan_to_num(concentration.double(), nan=0.5).clamp(0.0, 1.0)
    share = prior_share(alpha, conc, prior)
    beta = torch.minimum(torch.clamp(conc * (alpha + prior) - prior * share, min=0.0), alpha)  # undo the prior
    j = torch.nan_to_num(flux.double(), nan=0.0, posinf=0.0, neginf=0.0)
    faces = face_fluxes(j)
    if target is not None:
        goal = torch.nan_to_num(target.double(), nan=0.0, posinf=0.0, neginf=0.0).clamp(min=0.0)
        faces = consistent_faces(alpha, goal, faces, dt, spacing)
        j = _cell_speed_flux(faces, alpha)
    n = n_substeps or substeps(j, dt, spacing, alpha)
    # the sub-steps in NumPy: ~100 elementwise operations each on a few hundred cells, where a torch call costs
    # several times a NumPy one (the mixing advection was a fifth of a bed rollout step); elementwise float64
    # arithmetic in the same order, so the result is bit-identical to the same scheme in torch (no gradient flows
    # through it, as none did through the flux correction's transform: every caller advects under no_grad)
    device = alpha.device
    a_np, b_np = alpha.detach().cpu().numpy(), beta.detach().cpu().numpy()
    s_np, f_np = share.detach().cpu().numpy(), {a: f.detach().cpu().numpy() for a, f in faces.items()}
    for _ in range(n):
        a_np, b_np = _substep(a_np, b_np, s_np, f_np, dt / n, spacing, correction if scheme == "fct" else 0.0)
    alpha, beta = torch.from_numpy(a_np).to(device), torch.from_numpy(b_np).to(device)
    if target is not None:
        alpha, beta = _settle(alpha, beta, share, goal)
    conc = ((beta + prior * share) / (alpha + prior)).clamp(0.0, 1.0)
    return conc.to(concentration.dtype), alpha.to(solid_fraction.dtype)


SCHEMES = ("fct", "upwind")


def _concentration(alpha: np.ndarray, beta: np.ndarray, share: np.ndarray) -> np.ndarray:
    """Share of tagged solid in each cell, the global share where a cell holds none."""
    return np.clip(np.where(alpha > 0, beta / np.maximum(alpha, 1e-300), share), 0.0, 1.0)


def _along(x: np.ndarray, axis: int, start: int, length: int) -> np.ndarray:
    """The view of `x` from `start` for `length` entries along `axis` (torch's narrow)."""
    index = [slice(None)] * x.ndim
    index[axis] = slice(start, start + length)
    return x[tuple(index)]


def _settle(alpha: torch.Tensor, beta: torch.Tensor, share: torch.Tensor,
            target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Close the small gap the limiter leaves between the carried solid fraction and `target`: cells above it
    give the excess at their own concentration, cells below take what they lack at the pooled concentration of
    what was given. The tagged volume is kept exactly and every concentration stays a convex combination."""
    cells = tuple(range(1, alpha.ndim))
    c = torch.from_numpy(_concentration(alpha.cpu().numpy(), beta.cpu().numpy(), share.cpu().numpy())).to(alpha)
    gap = target - alpha
    give, take = (-gap).clamp(min=0.0), gap.clamp(min=0.0)
    given, wanted = give.sum(dim=cells, keepdim=True), take.sum(dim=cells, keepdim=True)
    pooled = torch.where(given > 0, (give * c).sum(dim=cells, keepdim=True) / given.clamp(min=1e-300), share)
    take = take * torch.where(wanted > 0, given / wanted.clamp(min=1e-300), torch.zeros_like(wanted))
    return alpha - give + take, beta - give * c + take * pooled


def _substep(alpha: np.ndarray, beta: np.ndarray, share: np.ndarray, face_flux: dict[int, np.ndarray],
             h: float, spacing: Sequence[float], correction: float) -> tuple[np.ndarray, np.ndarray]:
    c = _concentration(alpha, beta, share)
    axes = list(face_flux)
    outflow = np.zeros_like(alpha)
    raw = {}
    for a in axes:
        jf = face_flux[a] * (h / spacing[a])  # >0: from the lower cell to the upper one
        raw[a] = (np.maximum(jf, 0.0), np.maximum(-jf, 0.0))
        m = jf.shape[a + 1]
        _along(outflow, a + 1, 0, m)[...] += raw[a][0]
        _along(outflow, a + 1, 1, m)[...] += raw[a][1]
    # a cell gives at most what it holds (its upwind fluxes scaled by one factor)
    limit = np.where(outflow > alpha, alpha / np.maximum(outflow, 1e-300), 1.0)
    new_alpha = alpha - outflow * limit
    new_beta = new_alpha * c  # what stays keeps its concentration
    faces = {}
    for a in axes:
        m = alpha.shape[a + 1] - 1
        up = raw[a][0] * _along(limit, a + 1, 0, m)  # lower cell -> upper cell
        down = raw[a][1] * _along(limit, a + 1, 1, m)  # upper cell -> lower cell
        c_lo, c_hi = _along(c, a + 1, 0, m), _along(c, a + 1, 1, m)
        _along(new_alpha, a + 1, 1, m)[...] += up
        _along(new_alpha, a + 1, 0, m)[...] += down
        _along(new_beta, a + 1, 1, m)[...] += up * c_lo
        _along(new_beta, a + 1, 0, m)[...] += down * c_hi
        # antidiffusive flux (lower -> upper): central face concentration minus the upwind one
        faces[a] = correction * ((up - down) * 0.5 * (c_lo + c_hi) - (up * c_lo - down * c_hi))
    if correction == 0.0 or not faces:
        return new_alpha, new_beta
    # Zalesak's limiter: the corrections may not take any cell outside the range of c around it
    c_max, c_min = c.copy(), c.copy()
    gain, loss = np.zeros_like(alpha), np.zeros_like(alpha)
    for a, anti in faces.items():
        m = anti.shape[a + 1]
        c_lo, c_hi = _along(c, a + 1, 0, m), _along(c, a + 1, 1, m)
        np.maximum(_along(c_max, a + 1, 0, m), c_hi, out=_along(c_max, a + 1, 0, m))
        np.maximum(_along(c_max, a + 1, 1, m), c_lo, out=_along(c_max, a + 1, 1, m))
        np.minimum(_along(c_min, a + 1, 0, m), c_hi, out=_along(c_min, a + 1, 0, m))
        np.minimum(_along(c_min, a + 1, 1, m), c_lo, out=_along(c_min, a + 1, 1, m))
        _along(gain, a + 1, 1, m)[...] += np.maximum(anti, 0.0)
        _along(loss, a + 1, 0, m)[...] += np.maximum(anti, 0.0)
        _along(gain, a + 1, 0, m)[...] += np.maximum(-anti, 0.0)
        _along(loss, a + 1, 1, m)[...] += np.maximum(-anti, 0.0)
    room_up = np.maximum(c_max * new_alpha - new_beta, 0.0)
    room_down = np.maximum(new_beta - c_min * new_alpha, 0.0)
    r_up = np.where(gain > 0, np.minimum(room_up / np.maximum(gain, 1e-300), 1.0), 1.0)
    r_down = np.where(loss > 0, np.minimum(room_down / np.maximum(loss, 1e-300), 1.0), 1.0)
    for a, anti in faces.items():
        m = anti.shape[a + 1]
        to_upper = np.minimum(_along(r_up, a + 1, 1, m), _along(r_down, a + 1, 0, m))
        to_lower = np.minimum(_along(r_up, a + 1, 0, m), _along(r_down, a + 1, 1, m))
        limited = anti * np.where(anti > 0, to_upper, to_lower)
        _along(new_beta, a + 1, 1, m)[...] += limited
        _along(new_beta, a + 1, 0, m)[...] -= limited
    return new_alpha, new_beta


def prior_share(solid_fraction: torch.Tensor, concentration: torch.Tensor,
                prior: float = DEFAULT_PRIOR) -> torch.Tensor:
    """The global share p_B (B, 1, 1, 1) of a concentration field made with the prior: sum_c beta = p_B sum_c alpha
    and c = (beta + a0 p_B) / (alpha + a0) give p_B = sum c (alpha + a0) / (sum alpha + a0 n_cells)."""
    alpha, c = solid_fraction.double(), concentration.double()
    cells = alpha[0].numel()
    p = (c * (alpha + prior)).flatten(1).sum(1) / (alpha.flatten(1).sum(1) + prior * cells)
    return p.clamp(0.0, 1.0).view(-1, *([1] * (alpha.ndim - 1)))


def tagged_volume(solid_fraction: torch.Tensor, concentration: torch.Tensor,
                  prior: float = DEFAULT_PRIOR) -> torch.Tensor:
    """(B,) tagged solid volume (cell units) held by a (solid fraction, concentration) pair, the prior undone:
    beta = c (alpha + a0) - a0 p_B."""
    alpha, c = solid_fraction.double(), concentration.double()
    return (c * (alpha + prior) - prior * prior_share(alpha, c, prior)).flatten(1).sum(1)
