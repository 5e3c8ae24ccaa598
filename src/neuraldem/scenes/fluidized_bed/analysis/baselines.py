"""`neuraldem report fb-baselines dataset=DATASET out=DIR`: the cheapest honest answers for a held-out bed.

What a surrogate of the bed must beat, built from the training trajectories alone (CFD-DEM fields, no model)
and scored with the same functions, the same held-out trajectories and the same start snapshot as
`neuraldem evaluate` scores a checkpoint (`scenes.fluidized_bed.evaluation.compare`):

- `nearest`: the CFD-DEM trajectory at the nearest training inlet velocity, replayed as the answer (a lookup
  table of solver runs; its fluctuations are real ones, at a slightly different velocity);
- `interpolated`: snapshot by snapshot, the linear interpolation in inlet velocity between the two training
  trajectories that bracket the held-out velocity (the nearest one outside the range); a scalar regression on
  the scene parameter, whose averaging of two decorrelated beds damps the bubbles;
- `constant`: snapshot by snapshot, the mean of all training trajectories (ignores the velocity);
- `other_packing`: the solver's own seed spread: CFD-DEM at the same velocity from another initial packing (a
  held-out trajectory of the same part), replayed; scored only where such a twin exists.

A replayed trajectory is as long as the training runs (e.g. 300 steps), so against a long (30-s) test trajectory
the statistics cover that many steps only; the column "steps compared" says so. The solver's own seed spread
(`other_packing`) needs two packings per velocity; `neuraldem bench fb_speed_accuracy` charts it against cost.

Every result also holds `pooled` (`evaluation.compare_pooled`): the replayed series against all CFD-DEM runs at
the held-out velocity together, leaving out the one replayed (`other_packing`: 3 s of one packing against the
other two). `only=[SIM_ID,...]` scores just the named held-out trajectories (those a paired model was scored on).

`train_dataset=fb_small` takes the training trajectories (and other packings at the held-out velocity, of the same
part) from another dataset of the same scene: the baselines of a long validation set (`data=fb_small_longval`,
`part=val`), scored as a model trained on fb_small is scored there.

Each baseline is written as DIR/<baseline>/evaluation/metrics.json in the layout `neuraldem evaluate` writes,
so `neuraldem report fb-table` puts them in one table with the models.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.data.manifest import MANIFEST_NAME, Manifest, SimRecord
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import DataError
from neuraldem.machine import machine_info
from neuraldem.paths import invocation
from neuraldem.scenes.fluidized_bed.analysis.evaluation import (
    FieldSeries,
    _jsonable,
    aggregate,
    compare,
    compare_pooled,
    held_out,
    pooled_reference,
)
from neuraldem.scenes.fluidized_bed.dataset.report import metric_settings, resolve_dataset
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.rollout import DEFAULT_INIT_SNAPSHOT

BASELINES = ("nearest", "interpolated", "constant", "other_packing")
DESCRIPTIONS = {
    "other_packing": "CFD-DEM at the same velocity from another packing, replayed (the solver's seed spread)",
    "nearest": "CFD-DEM at the nearest training velocity, replayed",
    "interpolated": "CFD-DEM, snapshot-wise linear interpolation in velocity between the bracketing training runs",
    "constant": "CFD-DEM, snapshot-wise mean of all training runs",
}


def velocity(rec: SimRecord) -> float:
    return float(rec.params["inlet_velocity"])


def load_series(path: Path) -> FieldSeries:
    with BedFile(path) as f:
        return FieldSeries.from_dataset_file(f)


def blend(series: list[FieldSeries], weights: list[float]) -> FieldSeries:
    """The weighted sum of trajectories snapshot by snapshot, over the snapshots all of them have."""
    n = min(len(s.times) for s in series)
    first = series[0]

    def mix(get: Callable[[FieldSeries], np.ndarray]) -> np.ndarray:
        return sum(w * get(s)[:n].astype(np.float64) for s, w in zip(series, weights, strict=False))

    return FieldSeries(first.times[:n], mix(lambda s: s.solid_fraction), mix(lambda s: s.fluid_velocity),
                       mix(lambda s: s.mixing), first.grid, first.particle_volume, first.total_particle_volume)


def bracket(train: list[tuple[float, FieldSeries]], v: float) -> tuple[list[FieldSeries], list[float]]:
    """The two training runs around v and their linear weights; the nearest one alone outside the range."""
    lo = [t for t in train if t[0] <= v]
    hi = [t for t in train if t[0] >= v]
    if not lo or not hi:
        nearest = min(train, key=lambda t: abs(t[0] - v))
        return [nearest[1]], [1.0]
    (v0, s0), (v1, s1) = max(lo, key=lambda t: t[0]), min(hi, key=lambda t: t[0])
    if v1 == v0:
        return [s0], [1.0]
    w = (v - v0) / (v1 - v0)
    return [s0, s1], [1.0 - w, w]


def baseline_series(name: str, train: list[tuple[float, FieldSeries]], v: float) -> FieldSeries:
    if name == "nearest":
        return min(train, key=lambda t: abs(t[0] - v))[1]
    if name == "interpolated":
        return blend(*bracket(train, v))
    if name == "constant":
        return blend([s for _, s in train], [1.0 / len(train)] * len(train))
    raise DataError(f"unknown fluidized-bed baseline {name!r}", fix=f"choose from {', '.join(BASELINES)}")


def training_series(m: Manifest, dataset_dir: Path, split: str,
                    exclude: tuple[str, ...] = ()) -> list[tuple[float, FieldSeries]]:
    ids = m.split_ids(split, "train")
    unknown = sorted(set(exclude) - set(ids))
    if unknown:
        raise DataError(f"exclude=[{','.join(unknown)}]: not training trajectories of split {split!r} of "
                        f"{dataset_dir}", fix=f"choose from {', '.join(ids)}")
    records = [r for r in (m.record(i) for i in ids if i not in exclude) if r.usable]
    if not records:
        raise DataError(f"no finished training trajectories in split {split!r} of {dataset_dir}",
                        fix="generate them: neuraldem datagen data=fb_small")
    return sorted(((velocity(r), load_series(dataset_dir / str(r.file))) for r in records), key=lambda t: t[0])


def held_out_ids(m: Manifest, split: str, part: str, only: tuple[str, ...], dataset_dir: Path) -> list[SimRecord]:
    """The named held-out trajectories (of `part`, finished), in held_out's order; anything else is refused."""
    allowed = {r.sim_id for r in held_out(m, split, part, None)} | set(m.split_ids(split, part))
    wrong = sorted(set(only) - allowed)
    if wrong:
        raise DataError(f"only=[{','.join(wrong)}]: not {part} trajectories of split {split!r} of {dataset_dir}",
                        fix=f"choose from {', '.join(sorted(allowed))}")
    records = [m.record(i) for i in sorted(set(only))]
    unfinished = [r.sim_id for r in records if not r.usable]
    if unfinished:
        raise DataError(f"only=[{','.join(unfinished)}]: not finished in {dataset_dir}",
                        fix="generate them first: neuraldem datagen data=<dataset>")
    return sorted(records, key=lambda r: (r.params.get("duration", 0.0), r.params["inlet_velocity"], r.sim_id))


def training_manifest(train_dir: Path, m: Manifest) -> Manifest:
    """The manifest of train_dataset=, refused when its scene differs from the scored dataset's."""
    if not (Path(train_dir) / MANIFEST_NAME).is_file():
        raise DataError(f"train_dataset={train_dir}: no dataset there",
                        fix="give a dataset folder or name, e.g. train_dataset=fb_small")
    tm = Manifest.load(train_dir)
    if tm.scene != m.scene:
        raise DataError(f"train_dataset={train_dir}: its scene differs from {m.name!r}'s",
                        fix="take the training runs from a dataset of the same scene "
                            "(e.g. fb_small for fb_small_longval)")
    return tm


def part_runs(m: Manifest, dataset_dir: Path, split: str, part: str) -> list[tuple[Path, SimRecord]]:
    """The finished runs of one part of a split (with their dataset folder), by id."""
    ids = m.split_ids(split, part) if split in m.splits else []
    return sorted(((dataset_dir, r) for r in (m.record(i) for i in ids) if r.usable), key=lambda t: t[1].sim_id)


def evaluate_baselines(dataset_dir: Path, out_dir: Path, split: str = "velocity", part: str = "test",
                       baselines: tuple[str, ...] = BASELINES, init_snapshot: int = DEFAULT_INIT_SNAPSHOT,
                       max_sims: int | None = None, exclude: tuple[str, ...] = (),
                       only: tuple[str, ...] = (), train_dir: Path | None = None) -> dict[str, dict[str, Any]]:
    """Score every baseline on the held-out trajectories (`only`: just these, e.g. the ones a paired model was
    scored on), built from the training trajectories of `train_dir` (default: the same dataset); write
    <out>/<baseline>/evaluation/metrics.json."""
    for b in baselines:
        if b not in BASELINES:
            raise DataError(f"unknown fluidized-bed baseline {b!r}", fix=f"choose from {', '.join(BASELINES)}")
    m = Manifest.load(dataset_dir)
    settings = metric_settings(m)
    train_dir = Path(train_dir) if train_dir else Path(dataset_dir)
    tm = m if train_dir == Path(dataset_dir) else training_manifest(train_dir, m)
    train = training_series(tm, train_dir, split, exclude)
    train = [(v, s.since(init_snapshot)) for v, s in train]
    records = held_out(m, split, part, max_sims) if not only else held_out_ids(m, split, part, only, dataset_dir)
    if not records:
        raise DataError(f"no finished {part} trajectories in split {split!r} of {dataset_dir}")
    per_baseline: dict[str, list[dict[str, Any]]] = {b: [] for b in baselines}
    twins = part_runs(m, Path(dataset_dir), split, part)
    if tm is not m:  # other packings at the velocity from the training dataset's same part
        twins += part_runs(tm, train_dir, split, part)
    for rec in records:
        v = velocity(rec)
        truth = load_series(dataset_dir / str(rec.file)).since(init_snapshot)
        pooled_ids, pooled_series = pooled_reference(m, dataset_dir, rec, init_snapshot)  # read once per run
        for b in baselines:
            if b == "other_packing":
                twin_at = next(((d, r) for d, r in twins if (d, r.sim_id) != (Path(dataset_dir), rec.sim_id)
                                and round(velocity(r), 6) == round(v, 6)), None)
                if twin_at is None:  # one packing of this velocity so far
                    continue
                twin_dir, twin = twin_at
                pred = load_series(twin_dir / str(twin.file)).since(init_snapshot)
            else:
                pred = baseline_series(b, train, v)
            # pooled reference: every CFD-DEM run at the velocity, but the one replayed as the answer
            replayed = twin.sim_id if b == "other_packing" and twin_dir == Path(dataset_dir) else None
            kept = [(i, x) for i, x in zip(pooled_ids, pooled_series, strict=True) if i != replayed]
            ids, reference = [i for i, _ in kept], [x for _, x in kept]
            steps = len(pred.times) - 1
            result = {"sim_id": rec.sim_id, "inlet_velocity": v, "steps_requested": steps,
                      "extrapolation": not (train[0][0] <= v <= train[-1][0]),
                      "stability": {"steps_to_divergence": None, "divergence": None, "steps_done": steps,
                                    "horizons": []},
                      **compare(pred, truth, settings),
                      "pooled": compare_pooled(pred, reference, settings, ids)}
            per_baseline[b].append(result)
    horizon = min(len(s.times) for _, s in train) - 1
    out: dict[str, dict[str, Any]] = {}
    for b, results in per_baseline.items():
        if not results:
            continue
        doc = {
            "baseline": b, "description": DESCRIPTIONS[b], "dataset": str(dataset_dir), "split": split,
            "training_dataset": str(train_dir),
            "part": part, "trained_velocity_range": [train[0][0], train[-1][0]],
            "training_velocities": [v for v, _ in train], "excluded": list(exclude),
            "training": {"parameters": 0, "baseline": DESCRIPTIONS[b]},
            "training_horizon_steps": horizon, "horizons": [], "rollout_steps": horizon,
            "init_snapshot": init_snapshot, "metric_settings": settings,
            "aggregate": aggregate(results), "trajectories": results,
            "machine": machine_info(), "command": invocation(),
            "date_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        }
        folder = Path(out_dir) / f"baseline_{b}" / "evaluation"
        folder.mkdir(parents=True, exist_ok=True)
        atomic_write_json(folder / "metrics.json", _jsonable(doc))
        out[b] = doc
    return out


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = doc_parser("neuraldem.scenes.fluidized_bed.analysis.baselines", __doc__)
    p.add_argument("dataset", help="dataset folder or name under $NEURALDEM_DATA/datasets (e.g. fb_small)")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--split", default="velocity")
    p.add_argument("--part", default="test", choices=("train", "val", "test"))
    p.add_argument("--baselines", nargs="+", default=list(BASELINES), choices=BASELINES)
    p.add_argument("--init-snapshot", type=int, default=DEFAULT_INIT_SNAPSHOT)
    p.add_argument("--exclude", nargs="+", default=[], metavar="SIM_ID",
                   help="training trajectories to leave out (e.g. those a compared model was not trained on)")
    p.add_argument("--only", nargs="+", default=[], metavar="SIM_ID",
                   help="score just these held-out trajectories of part= (e.g. those a paired model was scored on; "
                        "default: the first of every held-out velocity)")
    p.add_argument("--train-dataset", default=None,
                   help="take the training runs (and other packings) from this dataset of the same scene (e.g. "
                        "fb_small, to score the baselines of fb_small_longval); default: the dataset itself")
    a = p.parse_args(argv)
    train_dir = resolve_dataset(a.train_dataset) if a.train_dataset else None
    docs = evaluate_baselines(resolve_dataset(a.dataset), a.out, a.split, a.part, tuple(a.baselines),
                              a.init_snapshot, exclude=tuple(a.exclude), only=tuple(a.only), train_dir=train_dir)
    for b, d in docs.items():
        g = d["aggregate"]
        print(f"{b:13s} mean rel L2 {g['solid_fraction_mean_rel_l2']:.3f}  Lacey MAE {g['lacey_mae']:.3f}  "
              f"({d['description']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
