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

from neuraldem.models.modules import compiled

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
    speed = np.moveaxis(flux.detach().cpu().double().numpy(), 1, 0)  # (3, B, ...)
    return _substep_count(np.abs(speed), solid_fraction.detach().cpu().double().numpy(), dt, spacing[:3])


def _substep_count(speed: np.ndarray, solid_fraction: np.ndarray, dt: float, spacing: Sequence[float]) -> int:
    """`substeps` on the per-axis flux magnitudes speed (k, ...) along axes of the k sizes `spacing` (an axis
    left out counts with zero: adding it changes no sum)."""
    scale = np.reshape(spacing, (-1,) + (1,) * (speed.ndim - 1))
    courant = speed / np.maximum(solid_fraction, COURANT_FLOOR) * dt / scale  # per axis, |u_s| dt / dx
    total = np.add.reduce(courant, axis=0)  # row after row, as the per-axis sum did
    worst = float(total.max()) if total.size else 0.0
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


@functools.lru_cache(maxsize=16)
def _eigenvalues(shape: tuple[int, ...], spacing: tuple[float, ...]) -> np.ndarray:
    """Eigenvalues (<= 0) of the cell-centred Neumann Laplacian in the DCT-II basis, the mean's set to 1 (no
    correction can move the mean); computed once per grid, as a rollout asks every step. Read-only."""
    lam = np.zeros(tuple(shape))
    for a, n in enumerate(shape):
        k = np.arange(n).reshape([-1 if b == a else 1 for b in range(len(shape))])
        lam = lam + (2.0 * np.cos(np.pi * k / n) - 2.0) / spacing[a] ** 2
    lam[(0,) * lam.ndim] = 1.0
    lam.flags.writeable = False
    return lam


def consistent_faces(solid_fraction: torch.Tensor, target: torch.Tensor, faces: dict[int, torch.Tensor],
                     dt: float, spacing: Sequence[float]) -> dict[int, torch.Tensor]:
    """The face fluxes plus the smallest gradient correction, -grad(psi), that makes their divergence carry
    `solid_fraction` to `target` over `dt` (module docstring). Lap(psi) = -(alpha - target - net outflow) / dt
    with closed walls; the part of the mismatch with a nonzero mean (unequal volumes) cannot be carried and
    is left out. No gradient flows through it (NumPy)."""
    grid = _grid(tuple(solid_fraction.shape))
    flat = np.concatenate([_flat64(faces[a]) for a in grid.axes] + [np.zeros(0)])
    out = grid.consistent(_flat64(solid_fraction), _flat64(target), flat, dt, spacing)
    return {a: torch.from_numpy(out[sl].reshape(faces[a].shape)).to(solid_fraction)
            for a, sl in zip(grid.axes, grid.slices, strict=True)}


def _flat64(x: torch.Tensor) -> np.ndarray:
    """A tensor's values as a flat float64 NumPy array (C order; a copy unless it already is one)."""
    x = x.detach().cpu()
    return (x.numpy() if x.dtype == torch.float32 else x.double().numpy()).astype(np.float64).reshape(-1)


@functools.lru_cache(maxsize=16)
def _grid(shape: tuple[int, ...]) -> _Grid:
    return _Grid(shape)


class _Grid:
    """Index arrays of one grid shape (B, nx, ny, nz), so that a step works on flat arrays with a few gathers
    instead of a slice per axis and face side (on a small grid the cost is the number of NumPy calls).

    Faces: the interior faces of every axis with more than one cell, axis after axis, each in C order (F in
    all). A quantity moved across them lives in a `vector`: [per cell (C) | lower -> upper part per face (F) |
    upper -> lower part (F) | 0]. Summing `into` rows (the cell's own value, then per axis the face below, which
    brings its lower -> upper part, and the face above, its upper -> lower part; a missing face points at the
    0) or `out_of` rows (what leaves: the face above's lower -> upper part, the face below's upper -> lower
    one) adds in the order of the per-axis loops it replaces, so the result is bit-identical to them."""

    def __init__(self, shape: tuple[int, ...]):
        batch, *cells = shape
        self.shape, self.batch = shape, batch
        self.size = c = math.prod(shape)
        self.axes = [a for a in range(3) if cells[a] > 1]
        index = np.arange(c).reshape(shape)
        flux_index = np.arange(3 * c).reshape(batch, 3, *cells)
        lo, hi, j_lo, j_hi, self.slices = [], [], [], [], []
        for a in self.axes:
            m, start = cells[a] - 1, sum(len(x) for x in lo)
            lo.append(_along(index, a + 1, 0, m).ravel())
            hi.append(_along(index, a + 1, 1, m).ravel())
            j_lo.append(_along(flux_index[:, a], a + 1, 0, m).ravel())
            j_hi.append(_along(flux_index[:, a], a + 1, 1, m).ravel())
            self.slices.append(slice(start, start + len(lo[-1])))
        self.faces = f = sum(len(x) for x in lo)
        lo_all, hi_all = (np.concatenate(x + [np.zeros(0, np.intp)]) for x in (lo, hi))
        self.ends = np.concatenate([lo_all, hi_all])  # each face's lower cell, then each face's upper cell
        self.flux_ends = np.concatenate(j_lo + j_hi + [np.zeros(0, np.intp)])  # the same in a (B, 3, ...) flux
        rows = 1 + 2 * len(self.axes)
        self.into = np.tile(np.arange(c), (rows, 1))
        self.into[1:] = c + 2 * f
        self.out_of, self.near = self.into.copy(), np.tile(np.arange(c), (rows, 1))
        for i, (sl, lo_a, hi_a) in enumerate(zip(self.slices, lo, hi, strict=True)):
            face = c + np.arange(sl.start, sl.stop)
            self.into[1 + 2 * i, hi_a], self.into[2 + 2 * i, lo_a] = face, f + face
            self.out_of[1 + 2 * i, lo_a], self.out_of[2 + 2 * i, hi_a] = face, f + face
            self.near[1 + 2 * i, lo_a], self.near[2 + 2 * i, hi_a] = hi_a, lo_a
        self.into_both = np.stack([self.into, self.into + c + 2 * f + 1])  # the same into two stacked vectors
        self.gain_loss = np.stack([self.into[1:], self.out_of[1:]])  # (2, rows - 1, C)
        # Zalesak's factor of a face: to the upper cell min(r_up[upper], r_down[lower]), to the lower one the
        # reverse, from the stacked (r_up, r_down) (2 C)
        self.ratio_ends = np.stack([np.stack([hi_all, c + lo_all]), np.stack([lo_all, c + hi_all])])

    def vector(self, *rows: int) -> np.ndarray:
        """An empty [cells | lower -> upper | upper -> lower | 0] vector (class docstring), or `rows` of them."""
        v = np.empty((*rows, self.size + 2 * self.faces + 1))
        v[..., -1] = 0.0
        return v

    def per_axis(self, out: np.ndarray, faces: np.ndarray, op, factors: Sequence[float]) -> np.ndarray:
        """out[faces of axis a] = op(faces of axis a, factors[a]) (a Python float per axis, as the loops had)."""
        for a, sl in zip(self.axes, self.slices, strict=True):
            op(faces[sl], factors[a], out=out[sl])
        return out

    def consistent(self, alpha: np.ndarray, target: np.ndarray, faces: np.ndarray, dt: float,
                   spacing: Sequence[float]) -> np.ndarray:
        """`consistent_faces` on flat arrays (faces: the F face fluxes)."""
        c, f = self.size, self.faces
        moved = self.vector()
        carried = self.per_axis(moved[c:c + f], faces, np.multiply, [dt / h for h in spacing])
        np.negative(carried, out=moved[c + f:-1])
        mismatch = alpha - target - np.add.reduce(moved[self.out_of[1:]], axis=0)  # the net outflow
        lam = _eigenvalues(self.shape[1:], tuple(float(h) for h in spacing))
        rhs = scipy.fft.dctn((-mismatch / dt).reshape(self.shape), type=2, axes=(1, 2, 3), norm="ortho") / lam
        rhs[:, 0, 0, 0] = 0.0
        psi = scipy.fft.idctn(rhs, type=2, axes=(1, 2, 3), norm="ortho").reshape(-1)[self.ends]
        step = psi[f:] - psi[:f]
        return faces - self.per_axis(step, step, np.divide, spacing)

    def cell_speeds(self, faces: np.ndarray) -> np.ndarray:
        """(axes, C) per-axis cell flux magnitude: the mean |face flux| of its two faces (0 at walls)."""
        c, f = self.size, self.faces
        half = self.vector()
        np.multiply(0.5, np.abs(faces), out=half[c:c + f])
        half[c + f:-1] = half[c:c + f]
        both = half[self.out_of[1:]]
        return both[0::2] + both[1::2]

    def substep(self, alpha: np.ndarray, beta: np.ndarray, share: np.ndarray, moving: np.ndarray,
                outflow: np.ndarray, outflow_floor: np.ndarray, correction: float) -> tuple[np.ndarray, np.ndarray]:
        """One donor-cell sub-step with Zalesak's flux correction. moving (2 F): the unlimited lower -> upper and
        upper -> lower volumes per face; outflow: their sum per cell."""
        c, f = self.size, self.faces
        conc = _concentration(alpha, beta, share)
        # a cell gives at most what it holds (its upwind fluxes scaled by one factor)
        limit = np.where(outflow > alpha, alpha / outflow_floor, 1.0)
        moved = self.vector(2)  # solid, tagged solid
        stay = np.subtract(alpha, outflow * limit, out=moved[0, :c])
        np.multiply(stay, conc, out=moved[1, :c])  # what stays keeps its concentration
        np.multiply(moving, limit[self.ends], out=moved[0, c:-1])
        conc_ends = conc[self.ends]  # the lower cells' c, then the upper ones'
        np.multiply(moved[0, c:-1], conc_ends, out=moved[1, c:-1])
        new_alpha, new_beta = np.add.reduce(moved.reshape(-1)[self.into_both], axis=1)
        if correction == 0.0 or not f:
            return new_alpha, new_beta
        up, down, tagged = moved[0, c:c + f], moved[0, c + f:-1], moved[1]
        # antidiffusive flux (lower -> upper): central face concentration minus the upwind one
        anti = correction * ((up - down) * 0.5 * (conc_ends[:f] + conc_ends[f:])
                             - (tagged[c:c + f] - tagged[c + f:-1]))
        # Zalesak's limiter: the corrections may not take any cell outside the range of c around it
        near = conc[self.near]
        room = np.empty((2, c))
        np.maximum.reduce(near, axis=0, out=room[0])
        np.minimum.reduce(near, axis=0, out=room[1])
        room *= new_alpha
        np.subtract(room[0], new_beta, out=room[0])
        np.subtract(new_beta, room[1], out=room[1])
        np.maximum(room, 0.0, out=room)  # room up, room down
        parts = self.vector()
        np.maximum(anti, 0.0, out=parts[c:c + f])
        np.maximum(-anti, 0.0, out=parts[c + f:-1])
        gain_loss = np.add.reduce(parts[self.gain_loss], axis=1)
        ratio = np.where(gain_loss > 0, np.minimum(room / np.maximum(gain_loss, 1e-300), 1.0), 1.0)
        ends = ratio.reshape(-1)[self.ratio_ends]
        to = np.minimum(ends[:, 0], ends[:, 1])  # to the upper cell, to the lower one
        limited = self.vector()
        limited[:c] = new_beta
        np.multiply(anti, np.where(anti > 0, to[0], to[1]), out=limited[c:c + f])
        np.negative(limited[c:c + f], out=limited[c + f:-1])
        return new_alpha, np.add.reduce(limited[self.into], axis=0)

    def cell_sums(self, *values: np.ndarray, flat: bool = False) -> list[np.ndarray]:
        """(B,) sums over the cells by torch, as `prior_share` (flat) and `_settle` take them (a NumPy sum adds
        in another order)."""
        if flat:
            return [torch.from_numpy(v.reshape(self.batch, -1)).sum(1).numpy() for v in values]
        cells = tuple(range(1, len(self.shape)))
        return [torch.from_numpy(v.reshape(self.shape)).sum(dim=cells, keepdim=True).numpy().reshape(-1)
                for v in values]

    def per_cell(self, per_row: np.ndarray) -> np.ndarray:
        return np.repeat(per_row, self.size // self.batch)


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
    as zero (a diverging model is caught by the rollout's checks, not here). No gradient flows through it."""
    if scheme not in SCHEMES:
        raise ValueError(f"unknown advection scheme {scheme!r}; known: {list(SCHEMES)}")
    if not 0.0 <= correction <= 1.0:
        raise ValueError(f"advection correction {correction} outside [0, 1]")
    # all in NumPy on flat arrays (`_Grid`): the grid is a few hundred cells, where each torch call costs
    # several NumPy ones; elementwise float64 arithmetic in the same order as the torch formulation, sums over
    # cells by torch (`_Grid.cell_sums`), so the result is bit-identical to it
    grid = _grid(tuple(solid_fraction.shape))
    c, f = grid.size, grid.faces
    alpha = np.maximum(_flat64(solid_fraction), 0.0)
    conc = _flat64(concentration)
    conc = _clip01(np.where(np.isnan(conc), 0.5, conc))
    weighted = conc * (alpha + prior)
    tagged_sum, solid_sum = grid.cell_sums(weighted, alpha, flat=True)
    share = grid.per_cell(_clip01(tagged_sum / (solid_sum + prior * (c // grid.batch))))  # prior_share
    beta = np.minimum(np.maximum(weighted - prior * share, 0.0), alpha)  # undo the prior
    j = _flat64(flux)
    j = np.where(np.isfinite(j), j, 0.0)
    ends = j[grid.flux_ends]
    faces = 0.5 * (ends[:f] + ends[f:])
    if target is not None:
        goal = _flat64(target)
        goal = np.maximum(np.where(np.isfinite(goal), goal, 0.0), 0.0)
        faces = grid.consistent(alpha, goal, faces, dt, spacing)
        n = n_substeps or _substep_count(grid.cell_speeds(faces), alpha, dt, [spacing[a] for a in grid.axes])
    else:
        speed = np.abs(j).reshape(grid.batch, 3, -1).transpose(1, 0, 2)
        n = n_substeps or _substep_count(speed, alpha.reshape(grid.batch, -1), dt, spacing[:3])
    moved = grid.vector()  # the unlimited volumes per face and sub-step, >0 from the lower cell to the upper one
    h = dt / n
    jf = grid.per_axis(np.empty(f), faces, np.multiply, [h / x for x in spacing])
    np.maximum(jf, 0.0, out=moved[c:c + f])
    np.maximum(-jf, 0.0, out=moved[c + f:-1])
    outflow = np.add.reduce(moved[grid.out_of[1:]], axis=0)
    outflow_floor = np.maximum(outflow, 1e-300)
    correction = correction if scheme == "fct" else 0.0
    if compiled.available():  # the same sub-steps compiled, bit for bit (`compiled`)
        alpha, beta = compiled.kernels().advection_substeps(n, alpha, beta, share, moved[c:-1], outflow, outflow_floor,
                                                float(correction), grid.ends, grid.into, grid.out_of, grid.near)
    else:
        for _ in range(n):
            alpha, beta = grid.substep(alpha, beta, share, moved[c:-1], outflow, outflow_floor, correction)
    if target is not None:
        alpha, beta = _settle(grid, alpha, beta, share, goal)
    conc = _clip01((beta + prior * share) / (alpha + prior))
    device = solid_fraction.device
    return (torch.from_numpy(conc.reshape(grid.shape)).to(device, concentration.dtype),
            torch.from_numpy(alpha.reshape(grid.shape)).to(device, solid_fraction.dtype))


SCHEMES = ("fct", "upwind")


def _concentration(alpha: np.ndarray, beta: np.ndarray, share: np.ndarray) -> np.ndarray:
    """Share of tagged solid in each cell, the global share where a cell holds none."""
    return _clip01(np.where(alpha > 0, beta / np.maximum(alpha, 1e-300), share))


def _clip01(x: np.ndarray) -> np.ndarray:
    """np.clip(x, 0, 1) in place, the same values (NaN kept) in a third of the time on a small array."""
    return np.minimum(np.maximum(x, 0.0, out=x), 1.0, out=x)


def _along(x: np.ndarray, axis: int, start: int, length: int) -> np.ndarray:
    """The view of `x` from `start` for `length` entries along `axis` (torch's narrow)."""
    index = [slice(None)] * x.ndim
    index[axis] = slice(start, start + length)
    return x[tuple(index)]


def _settle(grid: _Grid, alpha: np.ndarray, beta: np.ndarray, share: np.ndarray,
            target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Close the small gap the limiter leaves between the carried solid fraction and `target`: cells above it
    give the excess at their own concentration, cells below take what they lack at the pooled concentration of
    what was given. The tagged volume is kept exactly and every concentration stays a convex combination."""
    c = _concentration(alpha, beta, share)
    gap = target - alpha
    give, take = np.maximum(-gap, 0.0), np.maximum(gap, 0.0)
    given, wanted = grid.cell_sums(give, take)
    (given_c,) = grid.cell_sums(give * c)
    pooled = np.where(given > 0, given_c / np.maximum(given, 1e-300), share[::grid.size // grid.batch])
    take = take * grid.per_cell(np.where(wanted > 0, given / np.maximum(wanted, 1e-300), 0.0))
    return alpha - give + take, beta - give * c + take * grid.per_cell(pooled)


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
