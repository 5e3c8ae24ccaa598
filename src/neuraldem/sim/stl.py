"""ASCII STL meshes of surfaces of revolution (hopper wall, outlet plate, sink disk, heap tube)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np


def revolve(profile: list[tuple[float, float]], n_segments: int) -> np.ndarray:
    """Triangles (n, 3, 3) of the surface swept by the (r, z) polyline around the z axis."""
    theta = np.linspace(0.0, 2.0 * math.pi, n_segments + 1)
    c, s = np.cos(theta), np.sin(theta)
    tris = []
    for (r0, z0), (r1, z1) in zip(profile[:-1], profile[1:], strict=False):
        for i in range(n_segments):
            p00 = (r0 * c[i], r0 * s[i], z0)
            p01 = (r0 * c[i + 1], r0 * s[i + 1], z0)
            p10 = (r1 * c[i], r1 * s[i], z1)
            p11 = (r1 * c[i + 1], r1 * s[i + 1], z1)
            if r0 > 1e-12:  # a zero-radius edge would give a degenerate triangle
                tris.append((p00, p01, p11))
            if r1 > 1e-12:
                tris.append((p00, p11, p10))
    return np.asarray(tris, dtype=np.float64)


def polyline(a: tuple[float, float], b: tuple[float, float], max_edge: float) -> list[tuple[float, float]]:
    """Points from a to b spaced at most `max_edge` apart (keeps mesh elements of similar size)."""
    pa, pb = np.asarray(a, float), np.asarray(b, float)
    n = max(1, math.ceil(float(np.linalg.norm(pb - pa)) / max_edge))
    return [tuple(pa + (pb - pa) * k / n) for k in range(n + 1)]


def write_stl(path: Path, triangles: np.ndarray, name: str) -> None:
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    lines = [f"solid {name}"]
    for n, tri in zip(normals, triangles, strict=False):
        lines.append(f"  facet normal {n[0]:.6e} {n[1]:.6e} {n[2]:.6e}")
        lines.append("    outer loop")
        lines.extend(f"      vertex {v[0]:.6e} {v[1]:.6e} {v[2]:.6e}" for v in tri)
        lines.append("    endloop")
        lines.append("  endfacet")
    lines.append(f"endsolid {name}")
    path.write_text("\n".join(lines) + "\n")
