"""VTK output that ParaView opens: point clouds or grid fields per time step (.vtu) plus a .pvd time series."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import meshio
import numpy as np


def write_point_series(folder: Path, name: str, times: np.ndarray, points: list[np.ndarray],
                       point_data: list[dict[str, np.ndarray]]) -> Path:
    """One .vtu per time (vertex cells) and `<name>.pvd` that lists them with their times."""
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for k, (pts, data) in enumerate(zip(points, point_data, strict=False)):
        fname = f"{name}_{k:04d}.vtu"
        cells = [("vertex", np.arange(len(pts), dtype=np.int64)[:, None])]
        meshio.write(folder / fname, meshio.Mesh(np.asarray(pts, dtype=np.float64), cells,
                                                 point_data={k2: np.asarray(v) for k2, v in data.items()}))
        files.append(fname)
    return _write_pvd(folder, name, times, files)


def write_grid_series(folder: Path, name: str, times: np.ndarray, lo: Sequence[float], hi: Sequence[float],
                      shape: Sequence[int], cell_data: list[dict[str, np.ndarray]]) -> Path:
    """Fields on a regular grid over the box [lo, hi], each (nx, ny, nz) or (nx, ny, nz, C): one .vtu of
    hexahedra per time with the fields as cell data, and `<name>.pvd` listing them with their times."""
    nx, ny, nz = (int(n) for n in shape)
    axes = [np.linspace(lo[a], hi[a], n + 1) for a, n in enumerate((nx, ny, nz))]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    node = np.arange(len(points)).reshape(nx + 1, ny + 1, nz + 1)
    i, j, k = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"))
    corners = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
    hexahedra = np.stack([node[i + a, j + b, k + c] for a, b, c in corners], axis=1)  # cells in C order
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for step, data in enumerate(cell_data):
        fname = f"{name}_{step:04d}.vtu"
        fields = {key: [np.asarray(v).reshape(len(hexahedra), *np.shape(v)[3:])] for key, v in data.items()}
        meshio.write(folder / fname, meshio.Mesh(points, [("hexahedron", hexahedra)], cell_data=fields))
        files.append(fname)
    return _write_pvd(folder, name, times, files)


def _write_pvd(folder: Path, name: str, times: np.ndarray, files: list[str]) -> Path:
    entries = [f'    <DataSet timestep="{float(t):.6g}" part="0" file="{f}"/>'
               for t, f in zip(times, files, strict=False)]
    pvd = folder / f"{name}.pvd"
    pvd.write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
                   + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n")
    return pvd
