"""Does foamlib read what neuraldem's hand-written OpenFOAM reader reads? (the rule: use a well-kept
library where outputs stay identical.) Needs `pip install foamlib` (not a neuraldem dependency).

    python scripts/compare_foamlib.py case=CASE_DIR [cloud=kinematicCloud]

For every time directory: the cell fields alpha.air, U.air, p and the cloud's U, d, origId, read both ways,
compared exactly, with the median read time of each reader.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from neuraldem.cli import CommandParser
from neuraldem.sim.foam_reader import FoamCase, read_cell_field, read_cloud_field, time_dirs


def timed(fn: Callable[[], np.ndarray]) -> tuple[np.ndarray, float]:
    t0 = time.perf_counter()
    out = np.asarray(fn())
    return out, time.perf_counter() - t0


def main() -> None:
    import foamlib

    p = CommandParser(prog="python scripts/compare_foamlib.py", description=__doc__)
    p.add_argument("case", type=Path)
    p.add_argument("--cloud", default="kinematicCloud")
    a = p.parse_args()
    n_cells = FoamCase(a.case).n_cells  # a uniform field (time 0) is expanded to the mesh
    readers = {"cell": (lambda path: read_cell_field(path, n_cells),
                        lambda path: np.broadcast_to(foamlib.FoamFieldFile(path).internal_field,
                                                     read_cell_field(path, n_cells).shape)),
               "cloud": (read_cloud_field, lambda path: foamlib.FoamFile(path)[None])}
    rows: dict[str, list[tuple[bool, float, float]]] = {}
    for _, name in time_dirs(a.case):
        cloud = a.case / name / "lagrangian" / a.cloud
        files = [("cell", a.case / name / f) for f in ("alpha.air", "U.air", "p")]
        files += [("cloud", cloud / f) for f in ("U", "d", "origId")]
        for kind, path in files:
            if not path.is_file():
                continue
            ours_fn, lib_fn = readers[kind]
            ours, t_ours = timed(lambda: ours_fn(path))  # noqa: B023 - called at once
            theirs, t_lib = timed(lambda: lib_fn(path))  # noqa: B023 - called at once
            same = ours.size == theirs.size and np.array_equal(ours.reshape(theirs.shape), theirs)
            rows.setdefault(str(path.relative_to(a.case / name)), []).append((same, t_ours, t_lib))
    for field, r in rows.items():
        ours_ms = 1e3 * statistics.median(t for _, t, _ in r)
        lib_ms = 1e3 * statistics.median(t for *_, t in r)
        print(f"{field:<26} {sum(s for s, _, _ in r)}/{len(r)} identical; median read ms: neuraldem {ours_ms:.2f}, "
              f"foamlib {lib_ms:.2f}")


if __name__ == "__main__":
    main()
