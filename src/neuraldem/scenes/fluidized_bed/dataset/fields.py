"""Grid fields of a fluidized bed computed from the particles: kernel solid fraction and mixing concentration.

Solid fraction (the paper's filtered field alpha_p(r) = sum_i g_l(|r - r_i|) V_i, sec. 2.2) with a Gaussian
g_l of standard deviation `sigma`, averaged over each grid cell:

    alpha_p[c] = sum_i V_i * w_i[c] / V_cell,   w_i[c] = integral over cell c of the Gaussian at r_i

The Gaussian is mirrored at the box walls (method of images), so the part of a particle's kernel that would
fall outside the box is folded back in: every particle's weights sum to 1 and the field integrates to the
particles' total volume exactly (sum_c alpha_p[c] V_cell = sum_i V_i), at every grid resolution. The
Gaussian is separable, so w_i[c] = wx_i[a] * wy_i[b] * wz_i[k] with exact 1-D cell integrals (erf).

Mixing concentration: the volume fraction of particles of group B (those that started in the right half of
the box, x > x_mid at t = 0), kernel-weighted the same way (with its own, usually narrower kernel: a kernel
blurs the initial interface over ~sigma, which the Lacey index reads as mixing; see docs/fluidized-bed.md):

    c[c] = (alpha_B[c] + a0 * p_B) / (alpha_p[c] + a0)

with alpha_B the solid fraction of group-B particles, p_B the group-B share of all particle volume and
a0 = `prior_solid_fraction` (default 1e-3): inside the bed c is the local group-B fraction (changed by
< a0 / alpha_p, under 1 % where alpha_p > 0.1); in empty space, where the ratio is undefined, it tends
smoothly to the global share p_B instead of jumping (no NaNs for a model to learn).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtr

from neuraldem.sim.foam_reader import BoxGrid

DEFAULT_PRIOR = 1e-3


def axis_weights(x: np.ndarray, edges: np.ndarray, sigma: float) -> np.ndarray:
    """(N, n) share of each particle's 1-D Gaussian (std `sigma`, mirrored at edges[0] and edges[-1])
    that falls into each of the n cells between `edges`; rows sum to 1."""
    x = np.asarray(x, dtype=np.float64)
    a, b = float(edges[0]), float(edges[-1])
    length = b - a
    if sigma <= 0:
        raise ValueError("sigma must be positive")
    # images x + 2kL and 2a - x + 2kL; enough of them that the truncated tail is < 1e-15
    k_max = math.ceil(8.5 * sigma / (2 * length)) + 1
    shifts = 2.0 * length * np.arange(-k_max, k_max + 1)
    centres = np.concatenate([x[:, None] + shifts[None, :], (2 * a - x)[:, None] + shifts[None, :]], axis=1)
    cdf = ndtr((edges[None, None, :] - centres[:, :, None]) / sigma)  # (N, images, n + 1)
    w = np.diff(cdf, axis=2).sum(axis=1)
    return np.clip(w, 0.0, None)


def _deposit(positions: np.ndarray, values: np.ndarray, grid: BoxGrid, sigma: float,
             chunk: int = 20000) -> np.ndarray:
    """sum_i values_i * w_i[c] on the grid: (nx, ny, nz) for values (N,), (nx, ny, nz, C) for values (N, C)
    (the weights are computed once for all channels); particles with NaN positions are skipped."""
    ok = np.isfinite(positions).all(axis=1)
    p, v = positions[ok], np.asarray(values)[ok]
    vec = v.reshape(len(v), -1)  # (N, C)
    nx, ny, nz = grid.shape
    out = np.zeros((vec.shape[1], nx * ny, nz))
    edges = [grid.edges(a) for a in range(3)]
    for s in range(0, len(p), chunk):
        q, qv = p[s:s + chunk], vec[s:s + chunk]
        wx, wy, wz = (axis_weights(q[:, a], edges[a], sigma) for a in range(3))
        xy = (wx[:, :, None] * wy[:, None, :]).reshape(len(q), nx * ny)
        out += np.einsum("nx,nz,nc->cxz", xy, wz, qv, optimize=True)
    out = np.moveaxis(out.reshape(-1, nx, ny, nz), 0, -1)
    return out[..., 0] if np.ndim(values) == 1 else out


def particle_volumes(diameters: np.ndarray) -> np.ndarray:
    return math.pi / 6.0 * np.asarray(diameters, dtype=np.float64) ** 3


def solid_fraction(positions: np.ndarray, diameters: np.ndarray, grid: BoxGrid, sigma: float) -> np.ndarray:
    """(nx, ny, nz) kernel solid fraction of one snapshot (positions (N, 3), NaN rows = absent)."""
    return _deposit(positions, particle_volumes(diameters), grid, sigma) / grid.cell_volume


def group_b_share(labels: np.ndarray, diameters: np.ndarray) -> float:
    """p_B: group-B share of the particle volume."""
    vol = particle_volumes(diameters)
    return float(np.sum(vol * labels) / np.sum(vol))


def mixing_concentration(positions: np.ndarray, diameters: np.ndarray, labels: np.ndarray, grid: BoxGrid,
                         sigma: float, prior: float = DEFAULT_PRIOR, share: float | None = None,
                         alpha: np.ndarray | None = None) -> np.ndarray:
    """(nx, ny, nz) group-B concentration c (module docstring). `alpha`: the snapshot's solid fraction if
    already computed; `share`: p_B (default: from labels and diameters)."""
    vol = particle_volumes(diameters)
    alpha_b = _deposit(positions, vol * labels, grid, sigma) / grid.cell_volume
    if alpha is None:
        alpha = solid_fraction(positions, diameters, grid, sigma)
    p_b = group_b_share(labels, diameters) if share is None else share
    return (alpha_b + prior * p_b) / (alpha + prior)


def initial_labels(positions0: np.ndarray, grid: BoxGrid) -> np.ndarray:
    """Group B (1) = particle centre right of the box's mid-plane in x at t = 0; group A (0) otherwise."""
    x_mid = 0.5 * (grid.lo[0] + grid.hi[0])
    return (positions0[:, 0] > x_mid).astype(np.int8)


def displacements(positions: np.ndarray) -> np.ndarray:
    """(T - 1, N, 3): position at the next snapshot minus position now (NaN where either is absent)."""
    return positions[1:] - positions[:-1]


def trajectory_fields(positions: np.ndarray, diameters: np.ndarray, labels: np.ndarray, grid: BoxGrid,
                      sigma: float, mixing_sigma: float | None = None,
                      prior: float = DEFAULT_PRIOR) -> tuple[np.ndarray, np.ndarray]:
    """Solid fraction (kernel `sigma`) and mixing concentration (kernel `mixing_sigma`, default `sigma`)
    for every snapshot: two (T, nx, ny, nz) arrays."""
    mixing_sigma = sigma if mixing_sigma is None else mixing_sigma
    T = len(positions)
    alpha = np.empty((T, *grid.shape))
    conc = np.empty((T, *grid.shape))
    share = group_b_share(labels, diameters)
    for t in range(T):
        alpha[t] = solid_fraction(positions[t], diameters, grid, sigma)
        alpha_m = alpha[t] if mixing_sigma == sigma else None
        conc[t] = mixing_concentration(positions[t], diameters, labels, grid, mixing_sigma, prior, share, alpha_m)
    return alpha, conc


def solids_flux(positions: np.ndarray, displacement: np.ndarray, diameters: np.ndarray, grid: BoxGrid,
                sigma: float, dt: float) -> np.ndarray:
    """(nx, ny, nz, 3) kernel solids flux alpha_p u_s [m/s] of one step: each particle's volume times its
    velocity over the step (displacement / dt), deposited with the solid fraction's kernel at `positions`.
    The two-fluid model's conserved solids momentum per unit volume (divided by the solid density): zero in
    empty space, no division by a vanishing solid fraction. Rows with NaN are skipped."""
    vol = particle_volumes(diameters)
    ok = np.isfinite(positions).all(axis=1) & np.isfinite(displacement).all(axis=1)
    return _deposit(positions[ok], vol[ok, None] * displacement[ok] / dt, grid, sigma) / grid.cell_volume
