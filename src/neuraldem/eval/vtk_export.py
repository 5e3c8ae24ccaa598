"""VTK output that ParaView opens: point clouds per time step (.vtu) plus a .pvd time series."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np


def write_point_series(folder: Path, name: str, times: np.ndarray, points: list[np.ndarray],
                       point_data: list[dict[str, np.ndarray]]) -> Path:
    """One .vtu per time (vertex cells) and `<name>.pvd` that lists them with their times."""
    folder.mkdir(parents=True, exist_ok=True)
    entries = []
    for k, (t, pts, data) in enumerate(zip(times, points, point_data)):
        fname = f"{name}_{k:04d}.vtu"
        cells = [("vertex", np.arange(len(pts), dtype=np.int64)[:, None])]
        meshio.write(folder / fname, meshio.Mesh(np.asarray(pts, dtype=np.float64), cells,
                                                 point_data={k2: np.asarray(v) for k2, v in data.items()}))
        entries.append(f'    <DataSet timestep="{float(t):.6g}" part="0" file="{fname}"/>')
    pvd = folder / f"{name}.pvd"
    pvd.write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
                   + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n")
    return pvd
