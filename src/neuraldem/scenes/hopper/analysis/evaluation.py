"""Evaluate a hopper checkpoint against DEM and write metrics.json, a Table-4-style table, plots and VTK."""

from __future__ import annotations

import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.data.manifest import MANIFEST_NAME, Manifest, SimRecord
from neuraldem.data.normalization import HopperNormalizer
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import DataError, NeuraldemError
from neuraldem.eval.checkpoints import (
    IMPORTED_SPLIT,
    checkpoint_dataset,
    read_checkpoint,
    resolve_device,
    split_records,
)
from neuraldem.eval.vtk_export import write_point_series
from neuraldem.machine import machine_info
from neuraldem.paths import invocation
from neuraldem.scenes.hopper.analysis import plots as hopper_plots
from neuraldem.scenes.hopper.analysis.baselines import score_baseline
from neuraldem.scenes.hopper.analysis.metrics import layer_edges
from neuraldem.scenes.hopper.analysis.scoring import SimEvaluation, aggregate, dataset_metric_settings, evaluate_sims
from neuraldem.scenes.hopper.dataset.store import HopperFile
from neuraldem.scenes.hopper.surrogate.inference import ModelPredictor
from neuraldem.scenes.hopper.surrogate.module import HopperModule
from neuraldem.scenes.hopper.surrogate.predictors import DemPredictor, TrajectoryFields, time_grid

TABLE_SCALARS = ("mu_s", "mu_r", "theta", "repose")


def load_hopper_checkpoint(path: Path, device: str = "cpu") -> HopperModule:
    return read_checkpoint(path).module("hopper", device, "hopper evaluation")


def table_row(meta: dict[str, Any], agg: dict[str, float], method: str = "field model") -> str:
    marks = " | ".join("x" if s in meta["conditioning"] else "-" for s in TABLE_SCALARS)

    def field(key: str, scale: float) -> str:
        v = agg.get(key)
        return "-" if v is None or not np.isfinite(v) else f"{scale * v:.3f}"

    return (f"| {method} | {marks} | {agg['drainage_t95_pct_of_mean']:.1f} | {agg['drainage_mae_pct_of_mean']:.1f} | "
            f"{agg['residual_mae_pp']:.2f} | {agg['outflow_rel_err_pct']:.1f} | "
            f"{100 * agg['flow_regime_accuracy']:.0f} | {field('transport_mse', 100)} | "
            f"{field('residence_mse', 1000)} |")


TABLE_HEADER = ("| method | mu_s | mu_r | theta | repose (ffc substitute) | drainage t95 [% of mean] | drainage 1 % "
                "rule [% of mean] | residual MAE [pp] | outflow rel. error [%] | flow regime [% right] | "
                "transport MSE [1e-2] | residence MSE [1e-3] |\n"
                "|---|---|---|---|---|---|---|---|---|---|---|---|")


def baseline_scores(meta: dict[str, Any], m: Manifest, records: list[SimRecord],
                    truths: list[dict[str, float]] | None = None) -> dict[str, dict[str, Any]]:
    """The constant and the Gaussian process fitted on the runs the model trained and validated on, scored on
    the same runs as the model (every hopper table shows the cheapest honest alternatives beside the model),
    against `truths` when given (the field model's: imported runs), else the runs' stored metrics."""
    ids = meta.get("split_ids") or {}
    usable = {r.sim_id for r in m.usable()}
    train = [m.record(i) for i in ids.get("train", []) + ids.get("val", []) if i in usable]
    out: dict[str, dict[str, Any]] = {}
    for kind in ("constant", "gp"):
        try:
            r = score_baseline(kind, train, records, list(meta["conditioning"]), truths=truths)
        except NeuraldemError as err:
            out[kind] = {"skipped": str(err)}
            continue
        out[kind] = {k: r[k] for k in ("aggregate", "answer_s", "n_train", "n_extrapolated", "coverage_95")}
    return out


def evaluate_checkpoint(ckpt: Path, out_dir: Path, datasets_dir: Path, dataset_dir: Path | None = None,
                        split: str | None = None, part: str = "test", max_sims: int | None = None,
                        threshold: float = 0.5, vtk: bool = True, device: str = "auto",
                        progress: bool = True) -> dict[str, Any]:
    device = resolve_device(device)
    module = load_hopper_checkpoint(ckpt, device)
    meta = module.metadata
    dataset_dir, m = checkpoint_dataset(meta, Path(ckpt), datasets_dir, dataset_dir)
    records, split = checkpoint_records(meta, m, dataset_dir, split, part, max_sims)
    norm = HopperNormalizer.from_dict(meta["normalizer"])
    hop = meta["scene"]["hopper"]  # the model's scene (an imported dataset matches it within tolerance)
    times = time_grid(norm.horizon, float(hop["snapshot_interval"]))
    settings = dataset_metric_settings(m)
    if abs(float(meta["occupancy_radius_d"]) - settings.occupancy_radius_d) > 1e-9:
        raise DataError(f"checkpoint {ckpt} learned occupancy within {meta['occupancy_radius_d']} diameters, the "
                        f"metrics of {dataset_dir} count within {settings.occupancy_radius_d}: retrain it "
                        f"(data.metrics.occupancy_radius_d={settings.occupancy_radius_d})")
    radius = settings.occupancy_radius_d * float(hop["material"]["diameter"])
    model = ModelPredictor(module.net, norm, list(meta["conditioning"]), device=device)
    truth = DemPredictor(dataset_dir, radius, horizon=norm.horizon)
    box = np.asarray(norm.box_hi) - np.asarray(norm.box_lo)
    skipped: list[dict[str, str]] = []
    evals = evaluate_sims(records, dataset_dir, truth, model, times, box, norm.horizon, settings,
                          keep_fields=len(records), progress=progress, skipped=skipped)
    for s in skipped:
        print(f"warning: {s['sim_id']} not evaluated: {s['reason']}", file=sys.stderr)
    if not evals:
        raise DataError(f"none of the {len(records)} runs of {dataset_dir} lies inside the box checkpoint {ckpt} "
                        f"was trained on (e.g. {skipped[0]['reason']})")
    warn_extrapolation(evals)
    agg = aggregate(evals)
    evaluated = {e.sim_id for e in evals}
    # imported runs: every row against one truth, the DEM fields over the model's horizon (a run that ended
    # earlier holds its final state), whatever horizon the import stored its metrics over
    truths = [e.truth for e in evals] if m.scene.get("imported") else None
    stored = m.scene.get("hopper", {}).get("max_time") if truths is not None else None
    if stored is not None and abs(float(stored) - norm.horizon) > 1e-9:
        print(f"note: {dataset_dir} stores its metrics over {float(stored):g} s; every row here is scored over the "
              f"model's horizon, {norm.horizon:g} s", file=sys.stderr)
    baselines = baseline_scores(meta, training_manifest(meta, m, datasets_dir),
                                [r for r in records if r.sim_id in evaluated], truths)
    rows = [table_row(meta, agg)] + [table_row(meta, b["aggregate"], kind) for kind, b in baselines.items()
                                     if "aggregate" in b]
    out_dir.mkdir(parents=True, exist_ok=True)
    result = {
        "checkpoint": str(Path(ckpt).resolve()), "dataset": str(dataset_dir), "split": split, "part": part,
        "fold": meta.get("fold"), "n_folds": meta.get("n_folds"), "split_ids": meta.get("split_ids"),
        "metric_settings": settings.as_dict(),
        **({"truth": f"every row against the DEM fields over the model's horizon, {norm.horizon:g} s"}
           if truths is not None else {}),
        "conditioning": meta["conditioning"], "aggregate": agg, "table_row": rows[0], "table_rows": rows,
        "baselines": baselines,
        "simulations": [e.as_dict() for e in evals], "skipped": skipped, "machine": machine_info(),
        "command": invocation(), "date_utc": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    atomic_write_json(out_dir / "metrics.json", result)
    (out_dir / "table.md").write_text(TABLE_HEADER + "\n" + "\n".join(rows) + "\n")
    write_figures(evals, m, dataset_dir, times, out_dir, split, hop)
    if vtk:
        export_vtk(evals[0], m, dataset_dir, out_dir / "vtk", threshold)
    return result


def training_manifest(meta: dict[str, Any], m: Manifest, datasets_dir: Path) -> Manifest:
    """The manifest holding the runs the checkpoint trained on (the baselines are fitted on them): `m` itself,
    or for imported runs the training dataset under `datasets_dir` when it is there (else `m`: no baselines)."""
    if not m.scene.get("imported"):
        return m
    path = Path(datasets_dir) / meta["data_name"]
    return Manifest.load(path) if (path / MANIFEST_NAME).is_file() else m


def imported_records(meta: dict[str, Any], m: Manifest, dataset_dir: Path,
                     max_sims: int | None) -> list[SimRecord]:
    """Every finished imported run; each must carry the scalars the model is conditioned on."""
    records = m.usable()[:max_sims]
    for rec in records:
        missing = [k for k in meta["conditioning"] if k != "t" and k not in rec.conditioning()]  # t: the query time
        if missing:
            raise DataError(f"imported run {rec.sim_id} in {dataset_dir} lacks {', '.join(missing)}, which the "
                            f"model is conditioned on", fix="import it again with param=[" +
                            ",".join(f"{k}=VALUE" for k in missing) + "] (macro=[...] for measured ones)")
    return records


def checkpoint_records(meta: dict[str, Any], m: Manifest, dataset_dir: Path, split: str | None, part: str,
                       max_sims: int | None) -> tuple[list[SimRecord], str]:
    """The runs of `part` that the checkpoint was trained with (its recorded ids: a cross-validation fold,
    or the manifest's split as it was at training time), or those of another split of the manifest; every run
    of an imported dataset."""
    if m.scene.get("imported"):
        return imported_records(meta, m, dataset_dir, max_sims), IMPORTED_SPLIT
    ids = (meta.get("split_ids") or {}).get(part)
    if (split is None or split == meta["split"]) and ids:
        missing = [i for i in ids if i not in {r.sim_id for r in m.usable()}]
        if missing:
            raise DataError(f"{dataset_dir} lacks {len(missing)} of the checkpoint's {part} runs (e.g. "
                            f"{missing[0]}): evaluate on the dataset it was trained on")
        records = [m.record(i) for i in ids][:max_sims]
        return records, str(meta["split"])
    split = split or meta["split"]
    return split_records(m, dataset_dir, split, part, max_sims), split


def warn_extrapolation(evals: list[SimEvaluation]) -> None:
    """An answer outside the trained ranges is still given, but never silently."""
    for e in evals:
        if e.extrapolation:
            where = ", ".join(f"{k}={v[0]:.3g} (trained {v[1]:.3g} .. {v[2]:.3g})" for k, v in e.extrapolation.items())
            print(f"warning: {e.sim_id}: extrapolation, outside the trained range: {where}", file=sys.stderr)


def write_figures(evals: list[SimEvaluation], m: Manifest, dataset_dir: Path, times: np.ndarray,
                  out_dir: Path, split: str, hop: dict[str, Any]) -> None:
    hopper_plots.scatter_predicted_vs_dem(evals, out_dir / "predicted_vs_dem.png")
    by_index = sorted(evals, key=lambda e: np.nan_to_num(e.truth["mass_flow_index"], nan=-2.0))
    shown = ({"most funnel-like run": by_index[0], "most mass-flow-like run": by_index[-1]} if len(evals) > 1
             else {"the only run": by_index[0]})
    hopper_plots.stripes_over_time(shown, times, out_dir / "stripes.png")
    e = by_index[0]
    with HopperFile(dataset_dir / str(m.record(e.sim_id).file)) as f:
        points = f.initial_positions()
    hopper_plots.residence_slice(e, points, float(hop["material"]["diameter"]), out_dir / "residence_slice.png")
    if split == "band":
        train = [m.record(i).conditioning() for i in m.split_ids(split, "train")]
        hopper_plots.generalization_map(evals, train, out_dir / "generalization_map.png")


def export_vtk(e: SimEvaluation, m: Manifest, dataset_dir: Path, folder: Path, threshold: float,
               n_layers: int = 8) -> Path:
    """Predicted trajectory of one simulation: the occupied initial positions at each time, coloured by
    the predicted transport layer and residence time (open `<sim>_predicted.pvd` in ParaView)."""
    assert e.fields_predicted is not None
    with HopperFile(dataset_dir / str(m.record(e.sim_id).file)) as f:
        points = f.initial_positions()
    return predicted_point_series(points, e.fields_predicted, folder, f"{e.sim_id}_predicted", threshold, n_layers)


def predicted_point_series(points: np.ndarray, fp: TrajectoryFields, folder: Path, name: str, threshold: float,
                           n_layers: int = 8) -> Path:
    """The query points occupied at each time (occupancy >= threshold), with the predicted transport layer,
    residence time, occupancy and transport as point data: `<name>.pvd` for ParaView."""
    edges = layer_edges(points[:, 2], n_layers)
    pts, data = [], []
    for k in range(len(fp.times)):
        occ = fp.occupancy[k] >= threshold
        layer = np.clip(np.searchsorted(edges, fp.transport[k, occ, 2], side="right") - 1, 0, n_layers - 1)
        pts.append(points[occ])
        data.append({"transport_layer": layer.astype(np.int32), "residence_time": fp.residence[k, occ],
                     "occupancy": fp.occupancy[k, occ], "transport": fp.transport[k, occ]})
    return write_point_series(folder, name, fp.times, pts, data)
