"""Stability map of the hopper models across and beyond the trained friction range, over the cone angles of
the stored runs.

`neuraldem bench hopper_stability ckpt=[FIELD_CKPT,...] [gns_ckpt=[GNS_CKPT,...]] [labels=[...]]
[sims=4] [mu_s=[0.05,0.5,1.0,1.5,2.0]] [gns_steps=N] [limit_pct=5] [dataset=DIR] [out=PATH]`
writes results/hopper/stability/hopper_stability.json, .png and .md.

Cells: `sims=` stored test runs spread over the cone angle alpha (their geometry, packing, mu_r and alpha),
each asked at every `mu_s=` value (the trained range is the dataset's; values outside it are extrapolation).
An angle outside the trained range would need a packing LIGGGHTS never made, so alpha stays in range.

- Field surrogate (no rollout: every time is answered directly from the scalars) at the run's initial particle
  positions over its horizon. A time is unphysical when the occupied share of those points (occupancy > 0.5)
  is off the initial fill by more than `limit_pct=` % at t = 0, when it has risen by more than that above its
  running minimum (material appearing: a draining hopper only loses mass), or when more than that share of the
  points' transport (where the material came from) lies outside the hopper's box by over half a diameter.
  The stored run itself goes through the same checks at its own parameters (series "LIGGGHTS (stored run)"):
  the rule must pass the solver's own data, or it measures noise.
- GNS: the rollout of `gns.rollout` from the run's first H + 1 snapshots with the default checks (NaN,
  a particle leaving the box, a changed particle count, an overlapping pair): the first failing step.

Time until failure is reported in seconds of the trajectory (field: snapshot time; GNS: steps x dt).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.bench import plots
from neuraldem.bench.choices import default_labels
from neuraldem.bench.report import command_line, machine_info, resolve_out, write_results
from neuraldem.cli import command_parser
from neuraldem.config import checks
from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.errors import ConfigError, DataError
from neuraldem.gns.bench.points import load_hopper_gns, require_hopper_gns
from neuraldem.gns.datamodule import ParticleRun
from neuraldem.gns.rollout import Accelerator, model_accelerator, rollout
from neuraldem.paths import data_dir
from neuraldem.scenes.hopper.bench.surrogate import Question, answer, full_question, load_surrogate, surrogate_dataset
from neuraldem.scenes.hopper.dataset.store import HopperFile
from neuraldem.scenes.hopper.surrogate.predictors import DemPredictor, TrajectoryFields

NAME = "hopper_stability"
DEFAULT_MU_S = (0.05, 0.5, 1.0, 1.5, 2.0)
DEFAULT_LIMIT_PCT = 5.0
DEFAULT_SIMS = 4


def field_check(fields: TrajectoryFields, box_lo: np.ndarray, box_hi: np.ndarray, tolerance: float,
                limit_pct: float) -> dict[str, Any]:
    """The first unphysical time of a field answer (module docstring) and the worst value of each check."""
    occ = fields.occupancy > 0.5
    n_points = occ.shape[1]
    share = 100.0 * occ.sum(axis=1) / n_points
    fill_error = abs(share[0] - 100.0)
    rise = share - np.minimum.accumulate(share)
    outside = ((fields.transport < box_lo - tolerance) | (fields.transport > box_hi + tolerance)).any(axis=-1) & occ
    outside_pct = 100.0 * outside.sum(axis=1) / n_points
    candidates = []
    if fill_error > limit_pct:
        candidates.append((0, f"initial fill {share[0]:.1f} % of the particle positions (limit {limit_pct:g} % off)"))
    for values, what in ((rise, "occupied share rose by {:.1f} % (material created)"),
                         (outside_pct, "{:.1f} % of the points' transport outside the hopper")):
        beyond = np.flatnonzero(values > limit_pct)
        if beyond.size:
            candidates.append((int(beyond[0]), what.format(values[beyond[0]])))
    step, failure = min(candidates, key=lambda c: c[0]) if candidates else (None, "")
    times = fields.times
    return {"failed": step is not None, "failure": failure, "steps": len(times) - 1,
            "time_s": float(times[-1]), "failed_at_time_s": None if step is None else float(times[step]),
            "stable_time_s": float(times[-1]) if step is None else float(times[step]),
            "initial_fill_error_pct": float(fill_error), "max_rise_pct": float(rise.max()),
            "max_outside_pct": float(outside_pct.max())}


def pick_sims(m: Manifest, split: str, n: int) -> list[SimRecord]:
    """`n` test runs of `split` (validation runs if it has no test part) spread evenly over alpha."""
    ids = m.split_ids(split, "test") or m.split_ids(split, "val")
    if not ids:
        raise DataError(f"split {split!r} of {m.name} has no test or validation run")
    recs = sorted((m.record(i) for i in ids), key=lambda r: r.params["alpha"])
    idx = np.unique(np.round(np.linspace(0, len(recs) - 1, min(n, len(recs)))).astype(int))
    return [recs[i] for i in idx]


def with_mu_s(rec: SimRecord, mu_s: float) -> SimRecord:
    return dataclasses.replace(rec, params={**rec.params, "mu_s": float(mu_s)})


def _box(dataset_dir: Path, rec: SimRecord) -> tuple[np.ndarray, np.ndarray]:
    with HopperFile(dataset_dir / str(rec.file)) as f:
        return f.geometry.box()


def _cell(rec: SimRecord, mu_s: float, trained: tuple[float, float]) -> dict[str, Any]:
    return {"sim_id": rec.sim_id, "alpha": float(rec.params["alpha"]), "mu_r": float(rec.params["mu_r"]),
            "mu_s": float(mu_s), "inside_range": trained[0] <= mu_s <= trained[1]}


def field_series(ckpt: Path, label: str, sims: list[SimRecord], mu_s: list[float], dataset_dir: Path, m: Manifest,
                 limit_pct: float, trained: tuple[float, float]) -> dict[str, Any]:
    s = load_surrogate(ckpt)
    if "mu_s" not in s.metadata["conditioning"]:
        raise ConfigError(f"ckpt={ckpt} is conditioned on {s.metadata['conditioning']}, without mu_s: the friction "
                          "axis of this map does not apply to it (use a micro or all-scalars model)")
    diameter = float(m.scene["hopper"]["material"]["diameter"])
    points = []
    for rec in sims:
        q = full_question(m, dataset_dir, rec, s.predictor.norm)  # the run's positions, asked at every mu_s
        lo, hi = _box(dataset_dir, rec)
        for v in mu_s:
            fields = answer(s, Question(with_mu_s(rec, v), q.times, q.points))
            points.append({**_cell(rec, v, trained), **field_check(fields, lo, hi, 0.5 * diameter, limit_pct)})
    return {"label": label, "method": "field surrogate", "checkpoint": str(ckpt), "parameters": s.parameters,
            "conditioning": list(s.metadata["conditioning"]), "points": points}


def truth_series(sims: list[SimRecord], dataset_dir: Path, m: Manifest, limit_pct: float,
                 trained: tuple[float, float], horizon: float, occupancy_radius_d: float) -> dict[str, Any]:
    """The stored runs through the field checks at their own parameters (the rule's control), with the
    occupancy radius the models were trained with."""
    diameter = float(m.scene["hopper"]["material"]["diameter"])
    dem = DemPredictor(dataset_dir, occupancy_radius_d * diameter, horizon)
    interval = float(m.scene["hopper"]["snapshot_interval"])
    points = []
    for rec in sims:
        with HopperFile(dataset_dir / str(rec.file)) as f:
            pts, n, (lo, hi) = f.initial_positions(), f.n_snapshots, f.geometry.box()
        times = np.round(np.arange(n) * interval, 9)
        points.append({**_cell(rec, rec.params["mu_s"], trained),
                       **field_check(dem.fields(rec, times, pts), lo, hi, 0.5 * diameter, limit_pct)})
    return {"label": "LIGGGHTS (stored run)", "method": "solver", "points": points}


def gns_series(ckpt: Path, label: str, sims: list[SimRecord], mu_s: list[float], dataset_dir: Path, m: Manifest,
               steps: int | None, trained: tuple[float, float],
               accelerate: Accelerator | None = None) -> dict[str, Any]:
    module = load_hopper_gns(ckpt)
    meta, norm = module.metadata, module.norm
    if "mu_s" not in meta["conditioning"]:
        raise ConfigError(f"gns_ckpt={ckpt} is conditioned on {meta['conditioning']}, without mu_s")
    step_fn = accelerate or model_accelerator(module)
    points = []
    for rec in sims:
        with ParticleRun(dataset_dir / str(rec.file), "hopper", m.scene) as run:
            n = min(steps or run.n_snapshots, run.n_snapshots - norm.history - 1)
            for v in mu_s:
                r = rollout(step_fn, run, norm, norm.scalars(with_mu_s(rec, v).conditioning()), n)
                t = r.failed_at
                points.append({**_cell(rec, v, trained), "failed": t is not None, "failure": r.failure,
                               "steps": n, "time_s": n * run.dt,
                               "failed_at_time_s": None if t is None else t * run.dt,
                               "stable_time_s": (n if t is None else t) * run.dt,
                               "max_overlaps": max(r.overlaps, default=0)})
    return {"label": label, "method": "GNS", "checkpoint": str(ckpt), "conditioning": list(meta["conditioning"]),
            "points": points}


def run(ckpts: list[Path], gns_ckpts: list[Path] | None = None, labels: list[str] | None = None,
        n_sims: int = DEFAULT_SIMS, mu_s: list[float] | None = None, gns_steps: int | None = None,
        limit_pct: float = DEFAULT_LIMIT_PCT, dataset_dir: Path | None = None,
        accelerate: Accelerator | None = None) -> dict[str, Any]:
    """Every series of the map (`accelerate` replaces the GNS models, for tests)."""
    gns_ckpts = list(gns_ckpts or [])
    if not ckpts:
        raise ConfigError("ckpt= is required: give one or more hopper field-surrogate checkpoints")
    checks.positive_int("sims", n_sims)
    checks.number("limit_pct", limit_pct, lo=0.0, lo_open=True)
    if gns_steps is not None:
        checks.positive_int("gns_steps", gns_steps)
    for c in gns_ckpts:  # before the field series spend minutes
        require_hopper_gns(c)
    mu_s = sorted(float(v) for v in (mu_s or DEFAULT_MU_S))
    for i, v in enumerate(mu_s):
        checks.number(f"mu_s[{i}]", v, lo=0.0)
    names = list(labels) if labels else default_labels(ckpts + gns_ckpts)
    if len(names) != len(ckpts) + len(gns_ckpts):
        raise ConfigError(f"labels=: {len(names)} label(s) for {len(ckpts) + len(gns_ckpts)} checkpoint(s) "
                          "(ckpt= then gns_ckpt=): give one per checkpoint, or none")
    first = load_surrogate(ckpts[0])
    dataset_dir, m = surrogate_dataset(first, dataset_dir, data_dir() / "datasets")
    trained = tuple(float(x) for x in m.parameters["ranges"]["mu_s"])
    sims = pick_sims(m, first.metadata["split"], n_sims)
    series = [truth_series(sims, dataset_dir, m, limit_pct, trained, first.predictor.norm.horizon,
                           float(first.metadata["occupancy_radius_d"]))]
    series += [field_series(c, names[i], sims, mu_s, dataset_dir, m, limit_pct, trained) for i, c in enumerate(ckpts)]
    series += [gns_series(c, names[len(ckpts) + i], sims, mu_s, dataset_dir, m, gns_steps, trained, accelerate)
               for i, c in enumerate(gns_ckpts)]
    return {"dataset": str(dataset_dir), "scene": m.name, "mu_s_values": mu_s, "trained_mu_s_range": list(trained),
            "sims": [_cell(r, r.params["mu_s"], trained) for r in sims], "limit_pct": limit_pct, "series": series}


def summary_lines(results: dict[str, Any]) -> list[str]:
    lines = []
    for s in results["series"]:
        pts = s["points"]
        bad = [p for p in pts if p["failed"]]
        inside = [p for p in pts if p["inside_range"]]
        lines.append(f"{s['label']}: {len(bad)} of {len(pts)} cells failed ({sum(p['failed'] for p in inside)} of "
                     f"{len(inside)} inside the trained mu_s range)"
                     + (f"; first: {bad[0]['failure']}" if bad else ""))
    return lines


def render_markdown(results: dict[str, Any]) -> str:
    """Per series and cell: stable, or when and why it failed."""
    head = (f"Hopper stability map (limit {results['limit_pct']:g} %; trained mu_s range "
            f"{results['trained_mu_s_range']}):")
    lines = [head, ""]
    lines += [f"- {x}" for x in summary_lines(results)]
    lines += ["", "| series | sim | alpha [deg] | mu_s | in range | stable for [s] | failure |",
              "|---|---|---|---|---|---|---|"]
    for s in results["series"]:
        for p in s["points"]:
            lines.append(f"| {s['label']} | {p['sim_id']} | {p['alpha']:.1f} | {p['mu_s']:.2f} | "
                         f"{'yes' if p['inside_range'] else 'no'} | {p['stable_time_s']:.2f} of {p['time_s']:.2f} | "
                         f"{p['failure'] or '-'} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    p = command_parser(f"neuraldem.bench {NAME}", __doc__, summary=True)
    p.add_argument("--ckpt", type=Path, nargs="+", required=True, help="hopper field-surrogate checkpoints")
    p.add_argument("--gns-ckpt", type=Path, nargs="+", default=[], help="GNS checkpoints (experiment=gns_hopper)")
    p.add_argument("--labels", nargs="+", default=None, help="one per checkpoint, ckpt= first then gns_ckpt=")
    p.add_argument("--sims", type=int, default=DEFAULT_SIMS, help="stored test runs, spread over alpha")
    p.add_argument("--mu-s", type=float, nargs="+", default=list(DEFAULT_MU_S), help="sliding friction values")
    p.add_argument("--gns-steps", type=int, default=None, help="GNS steps per rollout (default: the whole run)")
    p.add_argument("--limit-pct", type=float, default=DEFAULT_LIMIT_PCT, help="tolerance of every check [%%]")
    p.add_argument("--dataset", type=Path, default=None, help="dataset dir (default: the checkpoint's)")
    p.add_argument("--out", type=Path, default=None, help=f"default results/hopper/stability/{NAME}.json (+ .png)")
    a = p.parse_args(argv)
    for c in [*a.ckpt, *a.gns_ckpt]:
        if not Path(c).is_file():
            raise DataError(f"checkpoint {c}: no such file")
    machine = machine_info()
    results = run(a.ckpt, a.gns_ckpt, a.labels, a.sims, a.mu_s, a.gns_steps, a.limit_pct, a.dataset)
    path = write_results(NAME, results, command=command_line(NAME, argv), path=resolve_out(a.out, NAME),
                         machine=machine)
    figure = plots.hopper_stability_figure(results, path.with_suffix(".png"))
    path.with_suffix(".md").write_text(render_markdown(results))
    print("\n".join(summary_lines(results)))
    print(f"wrote {path}, {figure} and {path.with_suffix('.md')}")
    return 0
