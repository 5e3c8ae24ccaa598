"""Fluidized-bed metrics: pure functions over arrays, for ground truth now and surrogate predictions later.

Fields are on a regular grid, indexed (T, nx, ny, nz[, 3]) with z the vertical axis; particles (T, N, 3).
Definitions (docs/fluidized-bed.md has the same, with the reasoning):

- time statistics: per-cell mean and standard deviation over the snapshots (solid fraction, fluid speed).
- total solid volume V_s(t) = sum_c alpha_p[c] V_cell; mass conservation error max_t |V_s(t) / V_s(0) - 1|.
- Lacey mixing index M = (s0^2 - s^2) / (s0^2 - sR^2) over sample cells = blocks of `block` grid cells
  (partial blocks at the box edge are smaller sample cells). For each sample cell k with n_k >= min_count
  particles and group-B fraction c_k: p = sum n_k c_k / sum n_k, s^2 = sum n_k (c_k - p)^2 / sum n_k
  (particle-count weighted), s0^2 = p (1 - p) (fully segregated), sR^2 = p (1 - p) / n_mean with n_mean =
  sum n_k / K (fully random). M = 0 segregated, ~1 random (not clipped: noise may give values above 1).
  From fields: n_k = sum alpha_p V_cell / V_particle, c_k = sum alpha_p c V_cell / sum alpha_p V_cell; from
  particles: n_k = centres in the block, c_k = their mean label.
- bed height H(t): the height below which a fraction `quantile` (default 0.95) of the solid volume lies
  (layer sums of the solid fraction, linear within a layer); `bed_height_particles`: the same quantile of
  the particle centres' heights.
- bubble fraction: share of the bed volume (grid cells below H(t), the top one partially) whose solid
  fraction is below `threshold` (default 0.15: nearly particle-free voids, vs ~0.5 in the dense phase).
- left-right structure of a per-cell statistic f (nx, ny, nz), the box being mirror-symmetric in x: mirror
  asymmetry ||f - f mirrored in x|| / ||f||; lean (right half - left half) / total (the middle column, for odd
  nx, in neither half); wall share: the part of the total in the nx // 6 columns next to either wall; and the
  error of a prediction split into its height profile (the x-mean at each height) and the lateral rest,
  profile^2 + lateral^2 = rel. L2^2 (orthogonal parts).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def fluid_speed(velocity: np.ndarray) -> np.ndarray:
    return np.linalg.norm(velocity, axis=-1)


def time_statistics(field: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-cell mean and standard deviation over axis 0 (time)."""
    return field.mean(axis=0), field.std(axis=0)


def total_solid_volume(solid_fraction: np.ndarray, cell_volume: float) -> np.ndarray:
    """(T,) solid volume [m^3] held by the field at each snapshot."""
    return solid_fraction.reshape(len(solid_fraction), -1).sum(axis=1) * cell_volume


def mass_conservation_error(volume: np.ndarray, reference: float | None = None) -> float:
    """max_t |V(t) / V_ref - 1|, V_ref = V(0) unless given (e.g. the particles' total volume)."""
    ref = float(volume[0]) if reference is None else float(reference)
    return float(np.max(np.abs(volume / ref - 1.0)))


def mirror_asymmetry(field: np.ndarray) -> float:
    """||f - f mirrored in x|| / ||f|| of a per-cell field (nx, ny, nz): 0 for a left-right symmetric one."""
    norm = float(np.linalg.norm(field))
    return float(np.linalg.norm(field - field[::-1]) / norm) if norm > 0 else float("nan")


def lean(field: np.ndarray) -> float:
    """(right half - left half) / total of a per-cell field (nx, ny, nz): where, e.g., the bubbles pass."""
    half = field.shape[0] // 2
    total = float(field.sum())
    if half == 0 or total == 0:  # one column: no sides
        return float("nan")
    return float((field[-half:].sum() - field[:half].sum()) / total)


def wall_share(field: np.ndarray, columns: int | None = None) -> float:
    """Share of a per-cell field's total (nx, ny, nz) in the `columns` (default nx // 6, at least 1) next to
    either side wall: of the std field, how much of the bubbling reaches the walls (uniform: 2 columns / nx)."""
    k = max(1, field.shape[0] // 6) if columns is None else columns
    if not 1 <= k <= field.shape[0] // 2:
        raise ValueError(f"wall_share: columns={k} must be 1 .. {field.shape[0] // 2} for {field.shape[0]} columns")
    total = float(field.sum())
    return float((field[:k].sum() + field[-k:].sum()) / total) if total != 0 else float("nan")


def profile_lateral_error(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """rel. L2 of pred vs truth (nx, ny, nz) split into the height profile's part (the x-mean at each height
    and y) and the lateral rest; profile**2 + lateral**2 == total**2. Tells a bed that expands wrongly from
    one whose bubbles take other paths across it."""
    norm = float(np.linalg.norm(truth))
    if norm == 0:
        return {"total": float("nan"), "profile": float("nan"), "lateral": float("nan")}
    err = pred - truth
    profile = np.broadcast_to(err.mean(axis=0, keepdims=True), err.shape)
    return {"total": float(np.linalg.norm(err) / norm), "profile": float(np.linalg.norm(profile) / norm),
            "lateral": float(np.linalg.norm(err - profile) / norm)}


def left_right_structure(pred_mean: np.ndarray, pred_std: np.ndarray, truth_mean: np.ndarray,
                         truth_std: np.ndarray) -> dict[str, float]:
    """The left-right diagnostics of a prediction's time-mean and std fields beside the reference's."""
    split = profile_lateral_error(pred_mean, truth_mean)
    return {"mean_profile_rel_l2": split["profile"], "mean_lateral_rel_l2": split["lateral"],
            "mean_asymmetry_pred": mirror_asymmetry(pred_mean), "mean_asymmetry_truth": mirror_asymmetry(truth_mean),
            "std_asymmetry_pred": mirror_asymmetry(pred_std), "std_asymmetry_truth": mirror_asymmetry(truth_std),
            "std_lean_pred": lean(pred_std), "std_lean_truth": lean(truth_std),
            "std_wall_share_pred": wall_share(pred_std), "std_wall_share_truth": wall_share(truth_std)}


def block_sums(field: np.ndarray, block: Sequence[int]) -> np.ndarray:
    """Sum the last three axes (nx, ny, nz) over blocks of `block` cells; edge blocks may be partial."""
    out = field
    for axis_from_end, b in zip((3, 2, 1), block, strict=False):
        axis = out.ndim - axis_from_end
        n = out.shape[axis]
        starts = np.arange(0, n, int(b))
        out = np.add.reduceat(out, starts, axis=axis)
    return out


def lacey_index(concentration: np.ndarray, counts: np.ndarray, min_count: float = 5.0) -> float:
    """M for one state from per-sample-cell group-B fractions and particle counts (module docstring)."""
    c = np.asarray(concentration, dtype=np.float64).ravel()
    n = np.asarray(counts, dtype=np.float64).ravel()
    keep = np.isfinite(c) & (n >= min_count)
    c, n = c[keep], n[keep]
    if len(n) == 0:
        return float("nan")
    total = n.sum()
    p = float(np.sum(n * c) / total)
    s0 = p * (1.0 - p)
    n_mean = total / len(n)
    sr = s0 / n_mean
    if s0 <= 0 or s0 - sr <= 0:
        return float("nan")
    s2 = float(np.sum(n * (c - p) ** 2) / total)
    return (s0 - s2) / (s0 - sr)


def lacey_from_fields(solid_fraction: np.ndarray, mixing: np.ndarray, cell_volume: float,
                      particle_volume: float, block: Sequence[int] = (2, 1, 2),
                      min_count: float = 5.0) -> np.ndarray:
    """(T,) Lacey index from the solid-fraction and mixing-concentration fields (T, nx, ny, nz)."""
    vol = block_sums(solid_fraction, block) * cell_volume
    vol_b = block_sums(solid_fraction * mixing, block) * cell_volume
    counts = vol / particle_volume
    with np.errstate(invalid="ignore", divide="ignore"):
        conc = vol_b / vol
    return np.array([lacey_index(conc[t], counts[t], min_count) for t in range(len(vol))])


def lacey_from_particles(positions: np.ndarray, labels: np.ndarray, lo: Sequence[float], hi: Sequence[float],
                         shape: Sequence[int], block: Sequence[int] = (2, 1, 2),
                         min_count: float = 5.0) -> np.ndarray:
    """(T,) Lacey index from particle centres (T, N, 3) and labels (N,) binned into the blocks of the grid
    (lo, hi, shape); absent (NaN) particles are skipped."""
    lo_a, hi_a = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    shape_a, block_a = np.asarray(shape), np.asarray(block)
    nb = -(-shape_a // block_a)  # blocks per axis (ceil)
    size = (hi_a - lo_a) / shape_a * block_a
    out = np.full(len(positions), np.nan)
    lab = np.asarray(labels, dtype=np.float64)
    for t, pos in enumerate(positions):
        ok = np.isfinite(pos).all(axis=1)
        idx = np.clip(((pos[ok] - lo_a) / size).astype(int), 0, nb - 1)
        flat = np.ravel_multi_index(idx.T, nb)
        counts = np.bincount(flat, minlength=int(np.prod(nb)))
        sums = np.bincount(flat, weights=lab[ok], minlength=int(np.prod(nb)))
        with np.errstate(invalid="ignore", divide="ignore"):
            out[t] = lacey_index(sums / counts, counts, min_count)
    return out


def bed_height(solid_fraction: np.ndarray, z_edges: np.ndarray, quantile: float = 0.95) -> np.ndarray:
    """(T,) height below which `quantile` of the solid volume lies (module docstring)."""
    layers = solid_fraction.sum(axis=(1, 2))  # (T, nz)
    out = np.full(len(layers), np.nan)
    for t, v in enumerate(layers):
        total = v.sum()
        if total <= 0:
            continue
        cum = np.concatenate([[0.0], np.cumsum(v)]) / total
        k = int(np.searchsorted(cum, quantile, side="left"))  # cum[k-1] < q <= cum[k]
        k = min(max(k, 1), len(v))
        frac = (quantile - cum[k - 1]) / max(cum[k] - cum[k - 1], 1e-300)
        out[t] = z_edges[k - 1] + np.clip(frac, 0.0, 1.0) * (z_edges[k] - z_edges[k - 1])
    return out


def bed_height_particles(positions: np.ndarray, quantile: float = 0.95) -> np.ndarray:
    """(T,) the `quantile` of the particle centres' heights."""
    return np.array([np.quantile(p[np.isfinite(p[:, 2]), 2], quantile) for p in positions])


def bubble_fraction(solid_fraction: np.ndarray, z_edges: np.ndarray, heights: np.ndarray,
                    threshold: float = 0.15) -> np.ndarray:
    """(T,) volume share of the bed (below heights[t]) in cells with solid fraction < threshold."""
    dz = np.diff(z_edges)
    out = np.full(len(solid_fraction), np.nan)
    for t, (a, h) in enumerate(zip(solid_fraction, heights, strict=False)):
        if not np.isfinite(h):
            continue
        w = np.clip((h - z_edges[:-1]) / dz, 0.0, 1.0)  # share of each layer below the bed surface
        if w.sum() <= 0:
            continue
        voids = (a < threshold).mean(axis=(0, 1))  # share of each layer's cells that are voids
        out[t] = float(np.sum(w * voids) / np.sum(w))
    return out


def first_crossing(times: np.ndarray, values: np.ndarray, level: float) -> float:
    """First time the series reaches `level` (NaN if never)."""
    hit = np.nonzero(np.asarray(values) >= level)[0]
    return float(times[hit[0]]) if len(hit) else float("nan")


def fb_summary(times: np.ndarray, solid_fraction: np.ndarray, mixing: np.ndarray, fluid_velocity: np.ndarray,
               z_edges: np.ndarray, cell_volume: float, particle_volume: float, total_particle_volume: float,
               block: Sequence[int] = (2, 1, 2), min_count: float = 5.0, bed_quantile: float = 0.95,
               bubble_threshold: float = 0.15) -> dict[str, float]:
    """Scalar ground-truth metrics of one trajectory from its fields (the same call scores predictions)."""
    h = bed_height(solid_fraction, z_edges, bed_quantile)
    bub = bubble_fraction(solid_fraction, z_edges, h, bubble_threshold)
    lacey = lacey_from_fields(solid_fraction, mixing, cell_volume, particle_volume, block, min_count)
    vol = total_solid_volume(solid_fraction, cell_volume)
    speed = fluid_speed(fluid_velocity)
    return {
        "bed_height_mean": float(np.nanmean(h)), "bed_height_std": float(np.nanstd(h)),
        "bubble_fraction_mean": float(np.nanmean(bub)), "bubble_fraction_max": float(np.nanmax(bub)),
        "lacey_initial": float(lacey[0]), "lacey_final": float(lacey[-1]),
        "lacey_time_to_0.5": first_crossing(times, lacey, 0.5),
        "solid_volume_error": mass_conservation_error(vol, total_particle_volume),
        "solid_fraction_mean": float(solid_fraction.mean()), "fluid_speed_mean": float(speed.mean()),
        "fluid_speed_max": float(speed.max()), "duration": float(times[-1]),
    }
