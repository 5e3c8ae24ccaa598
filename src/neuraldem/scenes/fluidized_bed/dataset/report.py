"""`neuraldem report fb-dataset dataset=DATASET out=DIR`: ground-truth report of a fluidized-bed dataset.

For the lowest and the highest inlet velocity among the dataset's finished trajectories (or the ones named
with sims=) it writes:
  curves.png          bed height, bubble fraction and Lacey index over time (field and particle versions)
  time_averages.png   per-cell time mean / std of solid fraction and fluid speed (central y slice)
  solid_volume.png    kernel-field solid volume relative to the particles' volume (mass conservation)
  report.json         the same series as numbers, the summary metrics, the solver cost of every trajectory
                      (CPU s per simulated s, with the machine load during the run) and the definitions
DATASET is a dataset folder or a dataset name under $NEURALDEM_DATA/datasets. note= is added to the titles
and the JSON (e.g. "short 1-s runs").
"""

from __future__ import annotations

import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.data.manifest import MANIFEST_NAME, Manifest, SimRecord, find_dataset
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import DataError
from neuraldem.machine import machine_info
from neuraldem.paths import data_dir
from neuraldem.scenes.fluidized_bed.analysis import metrics as fm
from neuraldem.scenes.fluidized_bed.analysis import plots as fb_plots
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile

DEFAULT_METRICS = {"lacey_block": [2, 1, 2], "lacey_min_count": 5.0, "bed_quantile": 0.95, "bubble_threshold": 0.15}


def resolve_dataset(arg: str) -> Path:
    path = find_dataset(arg)
    if (path / MANIFEST_NAME).is_file():
        return path
    named = data_dir() / "datasets" / arg
    raise DataError(f"no fluidized-bed dataset at {path} (nor {named})",
                    fix="pass a dataset folder, or generate one with `neuraldem datagen data=fb_small`")


def metric_settings(m: Manifest) -> dict[str, Any]:
    return {**DEFAULT_METRICS, **(m.parameters.get("metrics") or {})}


def trajectory_series(path: Path, settings: dict[str, Any]) -> dict[str, Any]:
    """Every metric over time for one stored trajectory, plus its per-cell time statistics."""
    block, min_count = tuple(settings["lacey_block"]), float(settings["lacey_min_count"])
    with BedFile(path) as f:
        alpha, mix, u, pos = f.solid_fraction(), f.mixing(), f.fluid_velocity(), f.positions()
        z = f.grid.edges(2)
        vp = f.particle_volumes
        h = fm.bed_height(alpha, z, settings["bed_quantile"])
        speed = fm.fluid_speed(u)
        a_mean, a_std = fm.time_statistics(alpha)
        s_mean, s_std = fm.time_statistics(speed)
        series = {
            "time": f.times, "bed_height": h,
            "bed_height_particles": fm.bed_height_particles(pos, settings["bed_quantile"]),
            "bubble_fraction": fm.bubble_fraction(alpha, z, h, settings["bubble_threshold"]),
            "lacey_field": fm.lacey_from_fields(alpha, mix, f.grid.cell_volume, float(vp.mean()), block, min_count),
            "lacey_particles": fm.lacey_from_particles(pos, f.labels, f.grid.lo, f.grid.hi, f.grid.shape, block,
                                                       min_count),
            "solid_volume": fm.total_solid_volume(alpha, f.grid.cell_volume),
            "particle_volume_total": float(vp.sum()),
        }
        stats = {"solid_fraction_mean": a_mean, "solid_fraction_std": a_std, "fluid_speed_mean": s_mean,
                 "fluid_speed_std": s_std}
        extent = (f.grid.lo[0], f.grid.hi[0], f.grid.lo[2], f.grid.hi[2])
    return {"series": series, "stats": stats, "extent": extent}


def choose(m: Manifest, sims: list[str] | None) -> list[SimRecord]:
    if sims:
        recs = [m.record(s) for s in sims]
        bad = [r.sim_id for r in recs if not r.usable]
        if bad:
            raise DataError(f"simulation(s) {bad} of {m.name!r} are not finished (status != ok)")
        return recs
    usable = sorted(m.usable(), key=lambda r: (r.params.get("inlet_velocity", 0.0), r.sim_id))
    if not usable:
        raise DataError(f"dataset {m.name!r} has no finished trajectory yet")
    return [usable[0], usable[-1]] if len(usable) > 1 else usable


def _jsonable(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return [None if not np.isfinite(x) else float(x) for x in v.ravel()]
    if isinstance(v, (float, np.floating)):
        return None if not np.isfinite(v) else float(v)
    return v


def build_report(dataset: Path, out: Path, sims: list[str] | None = None, note: str = "") -> dict[str, Any]:
    m = Manifest.load(dataset)
    if m.kind != "fluidized_bed":
        raise DataError(f"{dataset} holds a {m.kind!r} dataset; `neuraldem report fb-dataset` reads fluidized_bed "
                        "datasets")
    settings = metric_settings(m)
    recs = choose(m, sims)
    umf = m.parameters.get("minimum_fluidization_velocity_wen_yu")
    out.mkdir(parents=True, exist_ok=True)
    suffix = f" - {note}" if note else ""
    series, stats, entries = {}, {}, []
    extent = (0.0, 1.0, 0.0, 1.0)
    for r in recs:
        v = float(r.params.get("inlet_velocity", np.nan))
        label = f"U0 = {v:.2f} m/s" + (f" ({v / umf:.2f} Umf)" if umf else "")
        res = trajectory_series(dataset / str(r.file), settings)
        series[label], stats[label], extent = res["series"], res["stats"], res["extent"]
        entries.append({"sim_id": r.sim_id, "label": label, "params": r.params, "cost": r.cost,
                        "diagnostics": r.diagnostics, "metrics": {k: _jsonable(x) for k, x in r.metrics.items()},
                        "series": {k: _jsonable(x) for k, x in res["series"].items()}})
    fb_plots.plot_curves(series, out / "curves.png", f"{m.name}: ground truth (DPMFoam){suffix}")
    fb_plots.plot_time_averages(stats, extent, out / "time_averages.png",
                                f"{m.name}: time averages over the stored snapshots{suffix}")
    fb_plots.plot_solid_volume(series, out / "solid_volume.png", f"{m.name}: mass conservation of the kernel field")
    usable = m.usable()
    per_sim_s = [r.cost["cpu_s_per_simulated_s"] for r in usable if "cpu_s_per_simulated_s" in r.cost]
    report = {
        "dataset": str(dataset), "name": m.name, "note": note, "solver": m.solver,
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"), "machine": machine_info(),
        "metric_settings": settings, "fields": m.scene.get("fields"),
        "minimum_fluidization_velocity_wen_yu": umf,
        "dataset_size": {"simulations": len(m.simulations), "ok": len(usable),
                         "velocities": len({r.params.get("inlet_velocity") for r in usable})},
        "cost": {"cpu_s_per_simulated_s": {"median": _jsonable(float(np.median(per_sim_s))) if per_sim_s else None,
                                           "all": per_sim_s}},
        "definitions": {
            "bed_height": f"height below which {settings['bed_quantile']} of the kernel solid volume lies",
            "bubble_fraction": f"share of the bed volume (below the bed height) with solid fraction < "
                               f"{settings['bubble_threshold']}",
            "lacey": f"M = (s0^2 - s^2) / (s0^2 - sR^2) over sample cells of {settings['lacey_block']} grid cells "
                     f"with >= {settings['lacey_min_count']} particles, particle-count weighted",
        },
        "simulations": entries,
    }
    atomic_write_json(out / "report.json", report)
    return report


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = doc_parser("neuraldem.scenes.fluidized_bed.dataset.report", __doc__)
    p.add_argument("dataset", help="dataset folder or name")
    p.add_argument("--out", type=Path, required=True, help="output folder (created)")
    p.add_argument("--sims", nargs="*", help="sim ids to report (default: lowest and highest inlet velocity)")
    p.add_argument("--note", default="", help="added to the figure titles and the JSON")
    a = p.parse_args(argv)
    rep = build_report(resolve_dataset(a.dataset), a.out, a.sims, a.note)
    for e in rep["simulations"]:
        s = e["series"]
        cost = e["cost"].get("cpu_s_per_simulated_s", float("nan"))
        print(f"{e['sim_id']} {e['label']}: CPU s per simulated s {cost:.0f}, "
              f"mean bed height {1000 * np.nanmean(np.array(s['bed_height'], dtype=float)):.1f} mm, "
              f"mean bubble fraction {np.nanmean(np.array(s['bubble_fraction'], dtype=float)):.3f}, "
              f"Lacey {s['lacey_field'][0]:.2f} -> {s['lacey_field'][-1]:.2f}")
    print(f"wrote {a.out}/curves.png, time_averages.png, solid_volume.png, report.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
