"""The Numba kernels of `neuraldem.models.modules.compiled` (its docstring says why and how they are exact)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _max(a, b):  # np.maximum: NaN wins
    return a if (a >= b or a != a) else b


@numba.njit(cache=True, nogil=True)
def _min(a, b):  # np.minimum: NaN wins
    return a if (a <= b or a != a) else b


@numba.njit(cache=True, nogil=True)
def _sum_rows(values, rows, i):
    """values[rows[0, i]] + values[rows[1, i]] + ..., added in that order (NumPy's reduction over axis 0)."""
    acc = values[rows[0, i]]
    for r in range(1, rows.shape[0]):
        acc = acc + values[rows[r, i]]
    return acc


@numba.njit(cache=True, nogil=True)
def advection_substeps(n, alpha, beta, share, moving, outflow, outflow_floor, correction, ends, into, out_of, near):
    """`n` donor-cell sub-steps with Zalesak's flux correction (`_Grid.substep`, its docstring and names), on
    flat float64 arrays: alpha, beta, share, outflow, outflow_floor (C); moving (2 F) the unlimited lower ->
    upper, then upper -> lower volumes per face; ends (2 F) each face's lower, then upper cell; into, out_of,
    near (rows, C) `_Grid`'s index rows into a [cells | faces up | faces down | 0] vector. Returns the new
    (alpha, beta)."""
    c = alpha.shape[0]
    f = moving.shape[0] // 2
    rows = into.shape[0]
    size = c + 2 * f + 1
    conc = np.empty(c)
    limit = np.empty(c)
    solid = np.empty(size)
    tagged = np.empty(size)
    parts = np.zeros(size)
    limited = np.empty(size)
    conc_ends = np.empty(2 * f)
    anti = np.empty(f)
    ratio_up = np.empty(c)
    ratio_down = np.empty(c)
    new_alpha = np.empty(c)
    new_beta = np.empty(c)
    solid[size - 1] = 0.0
    tagged[size - 1] = 0.0
    limited[size - 1] = 0.0
    alpha = alpha.copy()
    beta = beta.copy()
    for _ in range(n):
        for i in range(c):
            q = beta[i] / _max(alpha[i], 1e-300) if alpha[i] > 0 else share[i]
            conc[i] = _min(_max(q, 0.0), 1.0)
            limit[i] = alpha[i] / outflow_floor[i] if outflow[i] > alpha[i] else 1.0
            stay = alpha[i] - outflow[i] * limit[i]
            solid[i] = stay
            tagged[i] = stay * conc[i]
        for k in range(2 * f):
            solid[c + k] = moving[k] * limit[ends[k]]
            conc_ends[k] = conc[ends[k]]
            tagged[c + k] = solid[c + k] * conc_ends[k]
        for i in range(c):
            new_alpha[i] = _sum_rows(solid, into, i)
            new_beta[i] = _sum_rows(tagged, into, i)
        if correction == 0.0 or f == 0:
            alpha, beta = new_alpha.copy(), new_beta.copy()
            continue
        for k in range(f):
            central = (solid[c + k] - solid[c + f + k]) * 0.5 * (conc_ends[k] + conc_ends[f + k])
            anti[k] = correction * (central - (tagged[c + k] - tagged[c + f + k]))
            parts[c + k] = _max(anti[k], 0.0)
            parts[c + f + k] = _max(-anti[k], 0.0)
        for i in range(c):
            hi = conc[near[0, i]]
            lo = hi
            for r in range(1, rows):
                hi = _max(hi, conc[near[r, i]])
                lo = _min(lo, conc[near[r, i]])
            up = _max(hi * new_alpha[i] - new_beta[i], 0.0)
            down = _max(new_beta[i] - lo * new_alpha[i], 0.0)
            gain = parts[into[1, i]]
            loss = parts[out_of[1, i]]
            for r in range(2, rows):
                gain = gain + parts[into[r, i]]
                loss = loss + parts[out_of[r, i]]
            ratio_up[i] = _min(up / _max(gain, 1e-300), 1.0) if gain > 0 else 1.0
            ratio_down[i] = _min(down / _max(loss, 1e-300), 1.0) if loss > 0 else 1.0
        for k in range(f):
            lower, upper = ends[k], ends[f + k]
            if anti[k] > 0:  # to the upper cell
                factor = _min(ratio_up[upper], ratio_down[lower])
            else:
                factor = _min(ratio_up[lower], ratio_down[upper])
            limited[c + k] = anti[k] * factor
            limited[c + f + k] = -limited[c + k]
        for i in range(c):
            limited[i] = new_beta[i]
        for i in range(c):
            beta[i] = _sum_rows(limited, into, i)
            alpha[i] = new_alpha[i]
    return alpha, beta


@numba.njit(cache=True, nogil=True)
def water_fill_rows(work, target, cap):
    """min(s x, cap) per row x of work (B, N) >= 0 with the s that makes the row sum target[row] (B, 1): the
    exact water filling of `_water_fill_numpy` (its docstring), the same operations in the same order. The
    second value is False when a row needs the fallback (every solid cell at the cap), left to the caller."""
    b, n = work.shape
    out = np.empty((b, n))
    taken = np.empty(n + 1)
    for row in range(b):
        srt = np.sort(work[row])[::-1]
        taken[0] = 0.0
        if n:
            acc = srt[0]
            taken[1] = acc
            for k in range(1, n):
                acc = acc + srt[k]
                taken[k + 1] = acc
        total = taken[n]
        floor = 1e-12 * _max(total, 1e-300)
        s = np.nan
        found = False
        for k in range(n + 1):
            tail = total - taken[k]
            rest = target[row, 0] - cap * float(k)
            scale = rest / _max(tail, 1e-300)
            largest_free = srt[k] if k < n else 0.0
            if rest >= 0 and tail > floor and scale * largest_free <= cap:
                s, found = scale, True
                break
        if not found:
            return out, False
        for i in range(n):
            out[row, i] = _min(_max(s, 0.0) * work[row, i], cap)
    return out, True
