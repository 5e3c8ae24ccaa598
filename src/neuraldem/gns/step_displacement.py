"""How far particles move between two stored snapshots, in particle diameters: the step a particle-based
learned simulator (the GNS baseline) has to predict. A per-particle error of a sizeable share of this, with
neighbours one diameter apart, is an overlap at once.

`neuraldem report step-displacement dataset=DATASET_DIR [runs=5] [out=FILE.json]` prints and writes the
distribution (median, 90th, 99th percentile, max) over every particle present in two consecutive snapshots
of the first `runs=` usable runs, for either scene.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.cli import command_parser, report_user_errors
from neuraldem.config import checks
from neuraldem.data.manifest import Manifest
from neuraldem.data.schema import atomic_write_json
from neuraldem.gns.datamodule import ParticleRun
from neuraldem.paths import module_command


def displacements(positions: np.ndarray, diameters: np.ndarray) -> np.ndarray:
    """|x_{t+1} - x_t| / d of every particle present at both t and t + 1 (positions (T, N, 3), NaN = absent)."""
    step = np.linalg.norm(np.diff(positions, axis=0), axis=-1) / diameters[None, :]  # (T - 1, N)
    return step[np.isfinite(step)]


def step_statistics(dataset_dir: Path, n_runs: int = 5) -> dict[str, Any]:
    """The distribution of per-snapshot displacements over the first `n_runs` usable runs of a dataset."""
    checks.positive_int("runs", n_runs)
    m = Manifest.load(dataset_dir)
    runs = m.usable()[:n_runs]
    values, dt = [], None
    for rec in runs:
        with ParticleRun(Path(dataset_dir) / str(rec.file), m.kind, m.scene) as run:
            values.append(displacements(run.positions(), run.diameters))
            dt = run.dt
    v = np.concatenate(values) if values else np.zeros(0)
    pct = (lambda q: float(np.percentile(v, q))) if v.size else (lambda q: float("nan"))
    return {"dataset": m.name, "kind": m.kind, "runs": [r.sim_id for r in runs], "snapshot_interval_s": dt,
            "n_displacements": int(v.size), "unit": "particle diameters per snapshot interval",
            "median": pct(50), "p90": pct(90), "p99": pct(99), "max": float(v.max()) if v.size else float("nan")}


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = command_parser("neuraldem.gns.step_displacement", __doc__, summary=True)
    p.add_argument("dataset", type=Path, help="a generated dataset folder (hopper or fluidized bed)")
    p.add_argument("--runs", type=int, default=5, help="the first N usable runs")
    p.add_argument("--out", type=Path, default=None, help="write the statistics to this JSON file")
    a = p.parse_args(argv)
    s = step_statistics(a.dataset, a.runs)
    print(f"{s['dataset']} ({s['kind']}), {len(s['runs'])} runs, snapshot interval {s['snapshot_interval_s']} s: "
          f"displacement per snapshot [particle diameters] median {s['median']:.3f}, p90 {s['p90']:.3f}, "
          f"p99 {s['p99']:.3f}, max {s['max']:.3f} ({s['n_displacements']} values)")
    if a.out is not None:
        s["command"] = module_command("neuraldem.gns.step_displacement", argv)
        atomic_write_json(a.out, s)
        print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
