"""Score a hopper predictor against DEM on a set of simulations: the practitioner's quantities
(drainage time, residual, outflow, flow regime) and the field errors (transport, residence MSE)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from neuraldem.data.hopper_store import HopperFile
from neuraldem.data.manifest import SimRecord
from neuraldem.eval.hopper_metrics import (
    flow_regime,
    hopper_summary,
    layer_edges,
    layer_stripes,
)
from neuraldem.eval.hopper_predict import HopperPredictor, TrajectoryFields

SCALARS = ("drainage_time", "residual_fraction", "outflow_rate", "mass_flow_index")


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

    def as_dict(self) -> dict[str, Any]:
        return {"sim_id": self.sim_id, "params": self.params, "truth": self.truth, "predicted": self.predicted,
                "transport_mse": self.transport_mse, "residence_mse": self.residence_mse}


def summarise(fields: TrajectoryFields, initial_z: np.ndarray, threshold: float, n_layers: int,
              drain_margin: float, mass_flow_threshold: float) -> tuple[dict[str, float], np.ndarray]:
    occupied = fields.occupancy >= threshold
    out = hopper_summary(fields.times, occupied, fields.transport[..., 2], initial_z, n_layers, drain_margin)
    out["mass_flow"] = float(flow_regime(out["mass_flow_index"], mass_flow_threshold) == "mass")
    return out, layer_stripes(occupied, fields.transport[..., 2], layer_edges(initial_z, n_layers))


def evaluate_sims(records: list[SimRecord], dataset_dir: Path, truth: HopperPredictor,
                  model: HopperPredictor, times: np.ndarray, box_size: np.ndarray, horizon: float,
                  threshold: float = 0.5, n_layers: int = 8, drain_margin: float = 0.01,
                  mass_flow_threshold: float = 0.5, keep_fields: int = 0, progress: bool = True) -> list[SimEvaluation]:
    out = []
    for i, rec in enumerate(tqdm(records, desc="evaluate", unit="sim", disable=not progress)):
        with HopperFile(dataset_dir / str(rec.file)) as f:
            points = f.initial_positions()
        ft = truth.fields(rec, times, points)
        fp = model.fields(rec, times, points)
        st, stripes_t = summarise(ft, points[:, 2], 0.5, n_layers, drain_margin, mass_flow_threshold)
        sp, stripes_p = summarise(fp, points[:, 2], threshold, n_layers, drain_margin, mass_flow_threshold)
        occ = ft.occupancy >= 0.5
        dt = ((fp.transport - ft.transport) / box_size)[occ]
        dr = ((fp.residence - ft.residence) / horizon)[occ]
        out.append(SimEvaluation(
            sim_id=rec.sim_id, params={**rec.params, **rec.macro}, truth=st, predicted=sp,
            transport_mse=float(np.mean(dt**2)) if dt.size else float("nan"),
            residence_mse=float(np.mean(dr**2)) if dr.size else float("nan"),
            stripes_truth=stripes_t, stripes_predicted=stripes_p,
            fields_truth=ft if i < keep_fields else None, fields_predicted=fp if i < keep_fields else None))
    return out


def aggregate(evals: list[SimEvaluation]) -> dict[str, float]:
    """Errors over all simulations, in the units of the paper's Table 4 (plus relative forms)."""
    def arr(kind: str, key: str) -> np.ndarray:
        return np.array([getattr(e, kind)[key] for e in evals], dtype=np.float64)

    drain_t, drain_p = arr("truth", "drainage_time"), arr("predicted", "drainage_time")
    res_t, res_p = arr("truth", "residual_fraction"), arr("predicted", "residual_fraction")
    out_t, out_p = arr("truth", "outflow_rate"), arr("predicted", "outflow_rate")
    ok = np.isfinite(out_t) & np.isfinite(out_p) & (out_t > 0)
    return {
        "n_sims": len(evals),
        "drainage_mae_s": float(np.mean(np.abs(drain_p - drain_t))),
        "drainage_mae_pct_of_mean": float(100 * np.mean(np.abs(drain_p - drain_t)) / np.mean(drain_t)),
        "residual_mae_pp": float(100 * np.mean(np.abs(res_p - res_t))),
        "outflow_rel_err_pct": float(100 * np.mean(np.abs(out_p[ok] - out_t[ok]) / out_t[ok])) if ok.any()
        else float("nan"),
        "flow_regime_accuracy": float(np.mean(arr("truth", "mass_flow") == arr("predicted", "mass_flow"))),
        "transport_mse": float(np.nanmean([e.transport_mse for e in evals])),
        "residence_mse": float(np.nanmean([e.residence_mse for e in evals])),
    }
