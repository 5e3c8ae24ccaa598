"""Mirror augmentation of fluidized-bed samples in x (the box's mid-plane).

Why: the bed (uniform inlet, equal side walls, gravity along -z) is symmetric under x -> lo + hi - x, so the
mirror image of a CFD-DEM trajectory is another trajectory of the same physics (another packing). Trained on
single 3-s windows, a model picks up their left-right accidents: the time-mean fields of single rollouts lean
to one wall where CFD-DEM's over many runs do not (results/fluidized_bed/recipe.md). Drawing the mirror image
for half the training samples doubles the data at no solver cost and teaches the symmetry instead of the
accidents.

What mirrors how: particle positions x -> lo + hi - x; every vector (displacement, fluid velocity, solids
flux) has its x component negated; grid fields are reversed along the cell axis x. The mixing concentration is
a passive share: its mirror image is the share of the mirrored group (group B started on the other side),
carried by the mirrored flow.
"""

from __future__ import annotations

import numpy as np


def mirror_points(pos: np.ndarray, lo_x: float, hi_x: float) -> np.ndarray:
    """(N, 3) positions reflected at the plane x = (lo_x + hi_x) / 2."""
    out = np.array(pos, copy=True)
    out[..., 0] = (lo_x + hi_x) - out[..., 0]
    return out


def mirror_vectors(v: np.ndarray) -> np.ndarray:
    """(..., 3) vectors of the mirrored flow: the x component changes sign."""
    out = np.array(v, copy=True)
    out[..., 0] = -out[..., 0]
    return out


def mirror_grid(field: np.ndarray, vector: bool) -> np.ndarray:
    """(nx, ny, nz, C) cell field of the mirrored bed: cells reversed along x (cell i <-> nx - 1 - i, which is
    the reflection when the cells span [lo_x, hi_x] evenly), x component negated for a vector field (C = 3)."""
    out = np.ascontiguousarray(field[::-1])
    return mirror_vectors(out) if vector else out
