"""`neuraldem report fb-reference-floor dataset=DATASET out=FILE.md`: how well short CFD-DEM series estimate a
bed's long-time statistics.

A 3000-step rollout is scored against references of different lengths: one 3-s run (`rel_l2_full`), all
packings at its velocity together (`pooled`, 3 x 3 s in fb_small) or one 30-s run (the long test
trajectories). Each reference has its own sampling error, a floor under which no model can be told apart from
CFD-DEM by it. This measures that floor on the long CFD-DEM trajectories themselves: each is cut into
consecutive windows of `window=` snapshots (default: as long as a training trajectory) from
`init_snapshot=` on, and the per-cell time mean and std of one window, and of `pool=` windows spread over the
run (as far apart as it allows, like independent packings), are compared with those of the whole trajectory
(relative L2, the functions `neuraldem evaluate` uses). Windows after the first start from a bed that has
been bubbling for seconds, unlike a fresh 3-s run, so the pooled floor is a slight underestimate for the
first window's transient. The Lacey index is not measured: mixing starts once, at t = 0.

The same run also bounds what a perfect model can score against it: its two halves are two (nearly)
independent samples of the bed, so rel. L2(first half, second half) is about sqrt(2) x the error of one half
against the infinite-time statistics, and a whole run's own error about half the halves' number (errors
falling as 1/sqrt(duration)). A rollout as long as the run, statistically exact, would then score about
sqrt(2) x that against it (`perfect_model_estimate`): the floor under the targets for the long test trajectories.

Writes FILE.md and FILE.json (per trajectory: every window's numbers, the pooled ones, which windows).
"""

from __future__ import annotations

import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import DataError
from neuraldem.machine import machine_info
from neuraldem.paths import invocation
from neuraldem.scenes.fluidized_bed.analysis.evaluation import (
    FieldSeries,
    _jsonable,
    concatenate,
    relative_l2,
    time_statistics,
)
from neuraldem.scenes.fluidized_bed.dataset.report import resolve_dataset
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.rollout import DEFAULT_INIT_SNAPSHOT

FIELDS = ("solid_fraction_mean", "solid_fraction_std", "fluid_speed_mean")


def windows(s: FieldSeries, length: int) -> list[FieldSeries]:
    """Consecutive, non-overlapping windows of `length` snapshots (a shorter rest is dropped)."""
    return [s.since(i * length).window(length) for i in range(len(s.times) // length)]


def spread(n: int, k: int) -> list[int]:
    """k of n window indices as evenly spread as possible, first and last included."""
    return sorted({int(round(x)) for x in np.linspace(0, n - 1, k)}) if k > 1 else [0]


def trajectory_floor(s: FieldSeries, window: int, pool: int) -> dict[str, Any]:
    """One window's and `pool` spread windows' statistics against the whole series' (see the module doc)."""
    parts = windows(s, window)
    if len(parts) < pool:
        raise DataError(f"a trajectory of {len(s.times)} snapshots holds {len(parts)} windows of {window}, fewer "
                        f"than pool={pool}", fix="use a longer trajectory or a smaller window= / pool=")
    whole = time_statistics(s)
    single = [{k: relative_l2(v, whole[k]) for k, v in time_statistics(w).items() if k in FIELDS} for w in parts]
    chosen = spread(len(parts), pool)
    pooled_stats = time_statistics(concatenate([parts[i] for i in chosen]))
    half = len(s.times) // 2
    first, second = time_statistics(s.window(half)), time_statistics(s.since(half).window(half))
    halves = {k: relative_l2(first[k], second[k]) for k in FIELDS}
    return {"snapshots": len(s.times), "window": window, "n_windows": len(parts), "single": single,
            "halves": halves, "whole_run_error_estimate": {k: v / 2 for k, v in halves.items()},
            "perfect_model_estimate": {k: v / np.sqrt(2) for k, v in halves.items()},
            "single_mean": {k: float(np.mean([x[k] for x in single])) for k in FIELDS},
            "single_max": {k: float(np.max([x[k] for x in single])) for k in FIELDS},
            "first_window": single[0], "pooled_windows": chosen,
            "pooled": {k: relative_l2(pooled_stats[k], whole[k]) for k in FIELDS}}


def long_records(m: Manifest, sims: tuple[str, ...]) -> list[SimRecord]:
    """The named finished trajectories, else the dataset's long trajectories (test; val in a long validation set)."""
    if sims:
        unknown = sorted(set(sims) - {r.sim_id for r in m.usable()})
        if unknown:
            raise DataError(f"sims=[{','.join(unknown)}]: not finished trajectories of this dataset",
                            fix="choose from the manifest's finished runs, e.g. its long test trajectories")
        return [m.record(i) for i in sims]
    long_ids = {i for part in m.splits.get("long", {}).values() for i in part}
    return [r for r in m.usable() if r.sim_id in long_ids]


def training_steps(m: Manifest, dataset_dir: Path) -> int:
    """Steps of the shortest training trajectory (= snapshots from snapshot 1 on, what a model's rollout is
    compared over); a set of long trajectories only (fb_small_longval) has the regular length in its table."""
    dt = float(m.scene["fluidized_bed"]["snapshot_interval"])
    steps = [round(float(m.record(i).params["duration"]) / dt) for i in m.split_ids("velocity", "train")
             if m.record(i).usable]
    if not steps and m.parameters.get("n_velocities") == 0 and m.parameters.get("duration"):
        steps = [round(float(m.parameters["duration"]) / dt)]
    if not steps:
        raise DataError(f"no finished training trajectories in {dataset_dir} to take the window length from",
                        fix="give window=SNAPSHOTS")
    return min(steps)


def measure(dataset_dir: Path, window: int | None = None, pool: int = 3, sims: tuple[str, ...] = (),
            init_snapshot: int = DEFAULT_INIT_SNAPSHOT) -> dict[str, Any]:
    m = Manifest.load(dataset_dir)
    window = training_steps(m, dataset_dir) if window is None else window
    if window < 2 or pool < 1:
        raise DataError(f"window={window} / pool={pool}: need a window of >= 2 snapshots and >= 1 window",
                        fix="e.g. window=300 pool=3")
    records = long_records(m, sims)
    if not records:
        raise DataError(f"no long trajectories in {dataset_dir}", fix="generate them (fb_small's sim_0090 - "
                        "sim_0092: neuraldem datagen data=fb_small first=[sim_0090]) or name sims=")
    rows = []
    for rec in records:
        with BedFile(dataset_dir / str(rec.file)) as f:
            s = FieldSeries.from_dataset_file(f).since(init_snapshot)
        rows.append({"sim_id": rec.sim_id, "inlet_velocity": float(rec.params["inlet_velocity"]),
                     **trajectory_floor(s, window, pool)})
    return {"dataset": str(dataset_dir), "window": window, "pool": pool, "init_snapshot": init_snapshot,
            "trajectories": rows, "machine": machine_info(), "command": invocation(),
            "date_utc": datetime.now(UTC).isoformat(timespec="seconds")}


def render(doc: dict[str, Any]) -> str:
    w, k = doc["window"], doc["pool"]
    lines = ["# How well short CFD-DEM series estimate the long-time statistics", "",
             (f"Dataset `{doc['dataset']}`; each long trajectory cut into windows of {w} snapshots from snapshot "
              f"{doc['init_snapshot']}; relative L2 of a window's per-cell statistics against the whole "
              f"trajectory's (mean and largest over its windows; the first window starts, like a training run, "
              f"from the fluidized start) and of {k} windows spread over the run taken together (like the pooled "
              "packings of a velocity)."), "",
             "| U0 [m/s] | trajectory (snapshots, windows) | reference | rel. L2 mean solid fraction "
             "| rel. L2 std solid fraction | rel. L2 mean fluid speed |", "|---|---|---|---|---|---|"]
    for r in doc["trajectories"]:
        head = f"| {r['inlet_velocity']:.3f} | {r['sim_id']} ({r['snapshots']}, {r['n_windows']})"
        for label, x in ((f"one window, mean over {r['n_windows']}", r["single_mean"]),
                         ("one window, largest", r["single_max"]), ("first window", r["first_window"]),
                         (f"{k} windows pooled ({', '.join(str(i) for i in r['pooled_windows'])})", r["pooled"]),
                         ("first half against second half", r["halves"]),
                         ("perfect model of the run's length against it (estimate)", r["perfect_model_estimate"])):
            lines.append(f"{head} | {label} | " + " | ".join(f"{x[f]:.3f}" for f in FIELDS) + " |")
    lines += ["", f"Command: `{doc['command']}`; {doc['date_utc']}; machine: {doc['machine'].get('cpu_model', '')}.",
              ""]
    return "\n".join(lines)


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = doc_parser("neuraldem.scenes.fluidized_bed.analysis.reference_floor", __doc__)
    p.add_argument("dataset", help="dataset folder or name under $NEURALDEM_DATA/datasets (e.g. fb_small)")
    p.add_argument("--out", type=Path, required=True, help="FILE.md (FILE.json beside it)")
    p.add_argument("--window", type=int, default=None, help="snapshots per window (default: a training run's)")
    p.add_argument("--pool", type=int, default=3, help="windows pooled, like packings of one velocity (3)")
    p.add_argument("--sims", nargs="+", default=[], metavar="SIM_ID", help="default: the long test trajectories")
    p.add_argument("--init-snapshot", type=int, default=DEFAULT_INIT_SNAPSHOT)
    a = p.parse_args(argv)
    doc = measure(resolve_dataset(a.dataset), a.window, a.pool, tuple(a.sims), a.init_snapshot)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(render(doc))
    atomic_write_json(a.out.with_suffix(".json"), _jsonable(doc))
    print(render(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
