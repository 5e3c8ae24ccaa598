"""Score hopper answers against DEM: the practitioner's quantities (drainage time t95 and the 1 %-rule,
residual, outflow, flow regime) and, for field models, the field errors (transport, residence MSE).

`score_answers` is the one place where errors are computed: the field model, the scalar baselines (constant,
Gaussian process) and LIGGGHTS rerun with other packing seeds are all scored by it, on the same runs.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.data.normalization import OutsideBoxError
from neuraldem.scenes.hopper.analysis.metrics import (
    SCALARS,
    HopperMetricSettings,
    hopper_summary,
    layer_edges,
    layer_stripes,
)
from neuraldem.scenes.hopper.dataset.store import HopperFile
from neuraldem.scenes.hopper.surrogate.predictors import HopperPredictor, TrajectoryFields

# error name -> (label, truth key, answer key); every table and chart uses these names
HOPPER_ERRORS = {
    "drainage_t95_pct_of_mean": "drainage time t95 error [% of mean]",
    "drainage_mae_pct_of_mean": "drainage time (1 % rule) error [% of mean]",
    "residual_mae_pp": "residual error [percentage points]",
    "outflow_rel_err_pct": "outflow rate error [%]",
}


@dataclass
class SimEvaluation:
    sim_id: str
    params: dict[str, float]
    truth: dict[str, float]
    predicted: dict[str, float]
    transport_mse: float  # normalised by the scene box size, over points occupied in DEM
    residence_mse: float  # normalised by the horizon, same points
    stripes_truth: np.ndarray = field(repr=False)
    stripes_predicted: np.ndarray = field(repr=False)
    fields_truth: TrajectoryFields | None = field(default=None, repr=False)
    fields_predicted: TrajectoryFields | None = field(default=None, repr=False)
    extrapolation: dict[str, list[float]] = field(default_factory=dict)  # scalars outside the trained range
    answer_s: float = float("nan")  # wall time of the predictor's fields for this run

    def as_dict(self) -> dict[str, Any]:
        return {"sim_id": self.sim_id, "params": self.params, "truth": self.truth, "predicted": self.predicted,
                "transport_mse": self.transport_mse, "residence_mse": self.residence_mse,
                "extrapolation": self.extrapolation, "answer_s": self.answer_s}


def dataset_metric_settings(m: Manifest) -> HopperMetricSettings:
    """The metric settings the dataset's stored metrics were computed with (defaults for older datasets)."""
    return HopperMetricSettings.from_config(m.metric_settings or {}, f"{m.name} manifest metric_settings")


def summarise(fields: TrajectoryFields, initial_z: np.ndarray,
              settings: HopperMetricSettings) -> tuple[dict[str, float], np.ndarray]:
    """Scalar metrics and layer stripes of one trajectory's fields (soft occupancy, no threshold)."""
    out = hopper_summary(fields.times, fields.occupancy, fields.transport[..., 2], initial_z, settings)
    edges = layer_edges(initial_z, settings.n_layers)
    return out, layer_stripes(fields.occupancy, fields.transport[..., 2], edges)


def evaluate_sims(records: list[SimRecord], dataset_dir: Path, truth: HopperPredictor,
                  model: HopperPredictor, times: np.ndarray, box_size: np.ndarray, horizon: float,
                  settings: HopperMetricSettings = HopperMetricSettings(),  # noqa: B008 frozen dataclass, immutable
                  keep_fields: int = 0, progress: bool = True,
                  skipped: list[dict[str, str]] | None = None) -> list[SimEvaluation]:
    """Model and truth on every run. With `skipped` (a list), a run whose query points lie far outside the
    box the model was trained on is recorded there ({sim_id, reason}) and the others are still evaluated;
    without it, that run is an error."""
    from tqdm import tqdm  # imported when runs are scored, not with the what-if path

    out = []
    for i, rec in enumerate(tqdm(records, desc="evaluate", unit="sim", disable=not progress)):
        with HopperFile(dataset_dir / str(rec.file)) as f:
            points, exits = f.initial_positions(), f.exit_times
        t0 = time.perf_counter()
        try:
            fp = model.fields(rec, times, points)
        except OutsideBoxError as err:
            if skipped is None:
                raise
            skipped.append({"sim_id": rec.sim_id, "reason": str(err)})
            continue
        answer_s = time.perf_counter() - t0
        ft = truth.fields(rec, times, points)
        st, stripes_t = summarise(ft, points[:, 2], settings)
        st["residual_fraction_particles"] = float(np.mean(~np.isfinite(exits)))
        sp, stripes_p = summarise(fp, points[:, 2], settings)
        occ = ft.occupancy >= 0.5
        dt = ((fp.transport - ft.transport) / box_size)[occ]
        dr = ((fp.residence - ft.residence) / horizon)[occ]
        flag = getattr(model, "extrapolation", None)
        out.append(SimEvaluation(
            sim_id=rec.sim_id, params={**rec.params, **rec.macro}, truth=st, predicted=sp,
            transport_mse=float(np.mean(dt**2)) if dt.size else float("nan"),
            residence_mse=float(np.mean(dr**2)) if dr.size else float("nan"),
            stripes_truth=stripes_t, stripes_predicted=stripes_p,
            fields_truth=ft if i < keep_fields else None, fields_predicted=fp if i < keep_fields else None,
            extrapolation=flag(rec) if flag is not None else {}, answer_s=answer_s))
    return out


def score_answers(truths: Sequence[dict[str, float]], answers: Sequence[dict[str, float]]) -> dict[str, float]:
    """Errors of scalar answers against DEM over a set of runs (the units of the paper's Table 4).

    Drainage errors are mean absolute errors as % of the mean DEM value; residual in percentage points of
    N0 (against the occupancy residual, and against the particle count that never left where the truth has
    it); outflow as the mean relative error; flow regime as the share of runs classified as DEM does."""
    def arr(rows: Sequence[dict[str, float]], key: str) -> np.ndarray:
        return np.array([r.get(key, np.nan) for r in rows], dtype=np.float64)

    out: dict[str, float] = {"n_sims": len(truths)}
    for key, seconds, percent in (("drainage_t95", "drainage_t95_mae_s", "drainage_t95_pct_of_mean"),
                                  ("drainage_time", "drainage_mae_s", "drainage_mae_pct_of_mean")):
        err = np.abs(arr(answers, key) - arr(truths, key))
        out[seconds] = float(np.mean(err))
        out[percent] = float(100 * np.mean(err) / np.mean(arr(truths, key)))
    res_p = arr(answers, "residual_fraction")
    out["residual_mae_pp"] = float(100 * np.mean(np.abs(res_p - arr(truths, "residual_fraction"))))
    res_particles = arr(truths, "residual_fraction_particles")
    out["residual_particles_mae_pp"] = float(100 * np.mean(np.abs(res_p - res_particles))) \
        if np.isfinite(res_particles).all() else float("nan")
    out_t, out_p = arr(truths, "outflow_rate"), arr(answers, "outflow_rate")
    ok = np.isfinite(out_t) & (out_t > 0)
    rel = np.abs(out_p[ok] - out_t[ok]) / out_t[ok]
    out["outflow_rel_err_pct"] = float(100 * np.mean(np.where(np.isfinite(rel), rel, 1.0))) if ok.any() \
        else float("nan")  # an answer without an outflow rate counts as 100 % off
    out["flow_regime_accuracy"] = float(np.mean(arr(truths, "mass_flow") == arr(answers, "mass_flow")))
    return out


def aggregate(evals: list[SimEvaluation]) -> dict[str, float]:
    """`score_answers` of a field model's evaluations, plus its field errors and extrapolation count."""
    out = score_answers([e.truth for e in evals], [e.predicted for e in evals])
    out["transport_mse"] = float(np.nanmean([e.transport_mse for e in evals]))
    out["residence_mse"] = float(np.nanmean([e.residence_mse for e in evals]))
    out["n_extrapolated"] = int(sum(bool(e.extrapolation) for e in evals))
    out["answer_s"] = float(np.median([e.answer_s for e in evals]))  # the field model's time per run
    return out


__all__ = ["HOPPER_ERRORS", "SCALARS", "SimEvaluation", "aggregate", "dataset_metric_settings", "evaluate_sims",
           "score_answers", "summarise"]
