"""`neuraldem report occupancy dataset=DATASET [runs=6] [radii=[0.6,0.8,1.0]] [times=[0.25,0.5,1,2]]`: how well
the occupancy field counts material, for a choice of occupancy radius.

The hopper metrics count material by the occupancy at the initial particle positions. Flowing material dilates:
its particles no longer sit on those positions, and a point in a void is empty unless some centre lies within
the radius. This prints, per run and time, the share of particles not yet exited (material still in the
hopper or falling below it) beside the occupied share of the initial positions for each radius: a radius that
reads far below the remaining share counts voids of flowing material as empty (0.6 diameters did on
hopper_small; 0.8 follows the material within a few % and is the default, docs/metrics.md).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.data.manifest import require_dataset
from neuraldem.errors import DataError
from neuraldem.scenes.hopper.dataset.fields import nearest_particle
from neuraldem.scenes.hopper.dataset.store import HopperFile


def coverage_rows(dataset: Path, n_runs: int, radii: list[float], times: list[float]) -> list[dict[str, float]]:
    """One row per (run, time): the remaining particle share and the occupied share per radius."""
    m = require_dataset(dataset, dataset.name)
    diameter = float(m.scene["hopper"]["material"]["diameter"])
    rows = []
    for rec in m.usable()[:n_runs]:
        with HopperFile(dataset / str(rec.file)) as f:
            points, exits, stored = f.initial_positions(), f.exit_times, f.times
            for t in times:
                k = int(np.argmin(np.abs(stored - t)))
                if abs(stored[k] - t) > 1e-6:
                    continue  # the run ended before t
                pos = f.positions(k)
                row = {"sim_id": rec.sim_id, "t": float(t), "remaining": float(np.mean(~(exits <= t)))}
                for r in radii:
                    row[f"r{r:g}"] = float(nearest_particle(points, pos, r * diameter)[0].mean())
                rows.append(row)
    if not rows:
        raise DataError(f"{dataset}: no usable run reaches the times {times}: pass earlier times=")
    return rows


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = doc_parser("neuraldem.scenes.hopper.dataset.occupancy_coverage", __doc__)
    p.add_argument("dataset", type=Path)
    p.add_argument("--runs", type=int, default=6, help="the first N usable runs")
    p.add_argument("--radii", type=float, nargs="+", default=[0.6, 0.8, 1.0], help="in particle diameters")
    p.add_argument("--times", type=float, nargs="+", default=[0.25, 0.5, 1.0, 2.0], help="[s] after opening")
    a = p.parse_args(argv)
    rows = coverage_rows(a.dataset, a.runs, a.radii, a.times)
    keys = [f"r{r:g}" for r in a.radii]
    print("| run | t [s] | particles not exited | " + " | ".join(f"occupied, r = {r:g} d" for r in a.radii) + " |")
    print("|---|---|---|" + "---|" * len(keys))
    for row in rows:
        print(f"| {row['sim_id']} | {row['t']:g} | {row['remaining']:.3f} | "
              + " | ".join(f"{row[k]:.3f}" for k in keys) + " |")
    gaps = {k: float(np.mean([row[k] - row["remaining"] for row in rows])) for k in keys}
    print("\nmean (occupied - not exited): " + ", ".join(f"{k[1:]} d: {v:+.3f}" for k, v in gaps.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
