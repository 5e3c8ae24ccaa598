"""`neuraldem report hopper-diagnosis`: where a hopper field model's answer errors come from, on its validation
runs, so that a fix aims at the cause.

    neuraldem report hopper-diagnosis [model=hopper_small] [dataset=DIR] [part=val] [max_sims=N]
                                      [out=results/hopper/accuracy/diagnosis.md]

Per run, the model's fields and the solver's at the run's own initial particle positions (as `neuraldem evaluate`
scores them), then two questions:

- The mass-flow index (the flow regime) reads two fields: the occupancy (when a place empties) and the transport
  field (from which layer of the fill the material there came). The index is recomputed with one field swapped
  for the solver's: (model occupancy, solver transport) and (solver occupancy, model transport). The field whose
  swap repairs the index is the one to fix. Beside it, the transport field's error in layer heights (median
  |dz| over occupied points, and the share of points more than half a layer off).
- Outflow and residual are fractions of the material: of N0, the number of query points, or of the fill, the
  model's own count at t = 0 (for the solver's 0/1 occupancy the two are equal). A field model's probabilities
  sum to a little less than N0 at t = 0, which read by N0 is a hopper that drains slowly. Both readings are
  given with their signed means (a bias: off in one direction on most runs) beside the mean absolute errors,
  for the fields at the run's particles (`evaluate`) and for the what-if answer `predict` gives at the run's
  parameters (lattice points, its answer budget: `whatif.ANSWER_BUDGET`).

Reads the model's training or validation runs only (`part=`); the test runs are read by `neuraldem release`.
Writes a markdown table and a JSON file beside it.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import ConfigError
from neuraldem.machine import machine_info
from neuraldem.paths import data_dir, module_command, results_dir
from neuraldem.scenes.hopper.analysis import metrics as hm

PARTS = ("val", "train")  # the test runs are the release's (`neuraldem release`)
SWAPS = {  # name -> (occupancy from, transport from)
    "model": ("model", "model"),
    "model occupancy, solver transport": ("model", "solver"),
    "solver occupancy, model transport": ("solver", "model"),
}


def index_swaps(times: np.ndarray, occupancy: dict[str, np.ndarray], transport_z: dict[str, np.ndarray],
                initial_z: np.ndarray, settings: hm.HopperMetricSettings) -> dict[str, float]:
    """The mass-flow index of each (occupancy, transport) pairing of `SWAPS`, and the solver's own ("solver").
    occupancy / transport_z: {"model": (T, Q), "solver": (T, Q)}."""
    edges = hm.layer_edges(initial_z, settings.n_layers)

    def index(occ: np.ndarray, tz: np.ndarray) -> float:
        return hm.mass_flow_index(times, hm.layer_stripes(occ, tz, edges))

    out = {"solver": index(occupancy["solver"], transport_z["solver"])}
    for name, (occ, tz) in SWAPS.items():
        out[name] = index(occupancy[occ], transport_z[tz])
    return out


def transport_error(model_z: np.ndarray, solver_z: np.ndarray, solver_occupancy: np.ndarray, initial_z: np.ndarray,
                    n_layers: int) -> dict[str, float]:
    """The transport field's height error over the points the solver has occupied, in layer heights."""
    edges = hm.layer_edges(initial_z, n_layers)
    layer = (edges[-1] - edges[0]) / n_layers
    occupied = solver_occupancy >= 0.5
    dz = np.abs(model_z - solver_z)[occupied] / layer if layer > 0 else np.zeros(0)
    if dz.size == 0:
        return {"median_abs_dz_layers": float("nan"), "share_over_half_layer": float("nan")}
    return {"median_abs_dz_layers": float(np.median(dz)), "share_over_half_layer": float(np.mean(dz > 0.5))}


def fill_readings(times: np.ndarray, occupancy: np.ndarray, settings: hm.HopperMetricSettings) -> dict[str, float]:
    """Outflow and residual of one occupancy (T, Q) as fractions of N0 (query points) and of the fill (count at
    t = 0), and the fill's share of N0."""
    counts = hm.occupied_counts(occupancy)
    n0 = float(occupancy.shape[1])
    fill = float(counts[0]) if counts[0] > 0 else n0
    out = {"fill_share": fill / n0}
    for name, base in (("n0", n0), ("fill", fill)):
        out[f"outflow_rate_{name}"] = hm.outflow_rate(times, counts, base, settings.tail_time, settings.outflow_window)
        out[f"residual_fraction_{name}"] = hm.residual_fraction(times, counts, base, settings.tail_time)
    return out


def diagnose_run(times: np.ndarray, solver: Any, model: Any, initial_z: np.ndarray,
                 settings: hm.HopperMetricSettings) -> dict[str, Any]:
    """Everything of one run (`solver`, `model`: TrajectoryFields at the same points and times)."""
    index = index_swaps(times, {"model": model.occupancy, "solver": solver.occupancy},
                        {"model": model.transport[..., 2], "solver": solver.transport[..., 2]}, initial_z, settings)
    counts = hm.occupied_counts(solver.occupancy)
    truth = {"outflow_rate": hm.outflow_rate(times, counts, float(counts[0]), settings.tail_time,
                                             settings.outflow_window),
             "residual_fraction": hm.residual_fraction(times, counts, float(counts[0]), settings.tail_time)}
    return {"mass_flow_index": index,
            "transport": transport_error(model.transport[..., 2], solver.transport[..., 2], solver.occupancy,
                                         initial_z, settings.n_layers),
            "solver": truth, "model": fill_readings(times, model.occupancy, settings)}


PATHS = {"model": "fields at the run's particles (evaluate)", "whatif": "what-if answer (lattice, answer budget)"}


def summarise(rows: list[dict[str, Any]], threshold: float) -> dict[str, Any]:
    """Means over the runs: index errors and regime calls per pairing; per path (`PATHS`, those the rows hold),
    the fill's share of N0 and the outflow and residual errors as fractions of N0 and of the fill."""
    solver = np.array([r["mass_flow_index"]["solver"] for r in rows])
    index = {}
    for name in SWAPS:
        values = np.array([r["mass_flow_index"][name] for r in rows])
        index[name] = {"mae": float(np.mean(np.abs(values - solver))),
                       "regime_right": float(np.mean((values > threshold) == (solver > threshold)))}
    paths = {path: {"fill_share": float(np.mean([r[path]["fill_share"] for r in rows])),
                    **{base: _errors(rows, path, base) for base in ("n0", "fill")}}
             for path in PATHS if all(path in r for r in rows)}
    return {"runs": len(rows), "mass_flow_index": index, "fractions_of": paths,
            "transport": {k: float(np.nanmean([r["transport"][k] for r in rows]))
                          for k in ("median_abs_dz_layers", "share_over_half_layer")}}


def _errors(rows: list[dict[str, Any]], path: str, base: str) -> dict[str, float]:
    truth = np.array([r["solver"]["outflow_rate"] for r in rows])
    rate = np.array([r[path][f"outflow_rate_{base}"] for r in rows])
    ok = np.isfinite(truth) & (truth > 0) & np.isfinite(rate)
    rel = (rate[ok] - truth[ok]) / truth[ok]
    res = np.array([r[path][f"residual_fraction_{base}"] - r["solver"]["residual_fraction"] for r in rows])
    return {"outflow_mae_pct": float(100 * np.mean(np.abs(rel))), "outflow_bias_pct": float(100 * np.mean(rel)),
            "outflow_runs_under": int(np.sum(rel < 0)), "outflow_runs": int(ok.sum()),
            "residual_mae_pp": float(100 * np.mean(np.abs(res))), "residual_bias_pp": float(100 * np.mean(res))}


def run(model_name: str, dataset: Path | None, part: str, max_sims: int | None) -> dict[str, Any]:
    from neuraldem import pretrained
    from neuraldem.data.normalization import HopperNormalizer
    from neuraldem.scenes.hopper.analysis.evaluation import (
        checkpoint_dataset,
        checkpoint_records,
        load_hopper_checkpoint,
        time_grid,
    )
    from neuraldem.scenes.hopper.analysis.scoring import dataset_metric_settings
    from neuraldem.scenes.hopper.dataset.store import HopperFile
    from neuraldem.scenes.hopper.predict import hopper_net
    from neuraldem.scenes.hopper.surrogate.inference import ModelPredictor
    from neuraldem.scenes.hopper.surrogate.predictors import DemPredictor
    from neuraldem.scenes.hopper.whatif import ANSWER_BUDGET, field_answer

    if part not in PARTS:
        raise ConfigError(f"part={part!r} is invalid: the diagnosis reads a model's {' or '.join(PARTS)} runs; its "
                          "test runs are read once, by neuraldem release", "e.g. part=val")
    model = pretrained.load(model_name, "hopper")
    ckpt = model.file("field")
    module = load_hopper_checkpoint(ckpt, "cpu")
    meta = module.metadata
    dataset_dir, m = checkpoint_dataset(meta, Path(ckpt), data_dir() / "datasets", dataset)
    records, _ = checkpoint_records(meta, m, dataset_dir, None, part, max_sims)
    norm = HopperNormalizer.from_dict(meta["normalizer"])
    hop = meta["scene"]["hopper"]
    times = time_grid(norm.horizon, float(hop["snapshot_interval"]))
    settings = dataset_metric_settings(m)
    solver = DemPredictor(dataset_dir, settings.occupancy_radius_d * float(hop["material"]["diameter"]),
                          horizon=norm.horizon)
    field = ModelPredictor(module.net, norm, list(meta["conditioning"]), device="cpu")
    net, answer_meta = hopper_net(model)
    rows = []
    for i, rec in enumerate(records, start=1):
        with HopperFile(dataset_dir / str(rec.file)) as f:
            points = f.initial_positions()
        row = diagnose_run(times, solver.fields(rec, times, points), field.fields(rec, times, points),
                           points[:, 2], settings)
        answer = field_answer(net, answer_meta, {k: rec.params[k] for k in model.meta["inputs"]}, settings,
                              budget=ANSWER_BUDGET)
        row["whatif"] = fill_readings(answer.fields.times, answer.fields.occupancy, settings)
        rows.append({"sim_id": rec.sim_id, "params": dict(rec.params), **row})
        print(f"{i}/{len(records)} {rec.sim_id}", file=sys.stderr)
    return {"model": model.name, "dataset": m.name, "part": part, "metric_settings": settings.as_dict(),
            "summary": summarise(rows, settings.mass_flow_threshold), "runs": rows}


def markdown(r: dict[str, Any]) -> str:
    s = r["summary"]
    lines = [f"# Where the hopper field model's errors come from ({r['model']}, {s['runs']} {r['part']} runs of "
             f"{r['dataset']})", "", "## Flow regime: which field", "",
             "| mass-flow index from | MAE vs the solver's | regime right |", "|---|---|---|"]
    for name, v in s["mass_flow_index"].items():
        lines.append(f"| {name} | {v['mae']:.3f} | {100 * v['regime_right']:.0f} % |")
    t = s["transport"]
    lines += ["", "The transport field's height error where the solver has material: median "
                  f"{t['median_abs_dz_layers']:.2f} layer heights per run (mean over runs); "
                  f"{100 * t['share_over_half_layer']:.0f} % of the points are more than half a layer off.", "",
              "## Outflow and residual: fractions of what", "",
              "| model answer | its count at t = 0 [% of N0] | fractions of | outflow MAE [%] | outflow bias [%] | "
              "runs under | residual MAE [pp] | residual bias [pp] |", "|---|---|---|---|---|---|---|---|"]
    for path, readings in s["fractions_of"].items():
        for base in ("n0", "fill"):
            v = readings[base]
            label = "N0 (query points)" if base == "n0" else "the fill (count at t = 0)"
            lines.append(f"| {PATHS[path]} | {100 * readings['fill_share']:.1f} | {label} | "
                         f"{v['outflow_mae_pct']:.2f} | {v['outflow_bias_pct']:+.2f} | "
                         f"{v['outflow_runs_under']} of {v['outflow_runs']} | {v['residual_mae_pp']:.2f} | "
                         f"{v['residual_bias_pp']:+.2f} |")
    lines += ["", "| run | alpha | index: solver | model | model occ., solver transport | "
                  "solver occ., model transport | median abs dz [layers] | outflow by N0 / by fill vs solver [%] |",
              "|---|---|---|---|---|---|---|---|"]
    for row in r["runs"]:
        ix, sol, mod = row["mass_flow_index"], row["solver"], row["model"]
        rel = [100 * (mod[f"outflow_rate_{k}"] / sol["outflow_rate"] - 1) if sol["outflow_rate"] > 0 else float("nan")
               for k in ("n0", "fill")]
        lines.append(f"| {row['sim_id']} | {row['params'].get('alpha', float('nan')):.1f} | {ix['solver']:+.2f} | "
                     f"{ix['model']:+.2f} | {ix['model occupancy, solver transport']:+.2f} | "
                     f"{ix['solver occupancy, model transport']:+.2f} | "
                     f"{row['transport']['median_abs_dz_layers']:.2f} | {rel[0]:+.1f} / {rel[1]:+.1f} |")
    return "\n".join(lines) + "\n"


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = doc_parser("neuraldem.scenes.hopper.analysis.diagnosis", __doc__)
    p.add_argument("--model", default="hopper_small", help="a shipped or released hopper model")
    p.add_argument("--dataset", type=Path, default=None, help="its dataset (default: the model's in the data dir)")
    p.add_argument("--part", default="val", help=f"the model's runs to read: {', '.join(PARTS)}")
    p.add_argument("--max-sims", type=int, default=None, help="the first N of them")
    p.add_argument("--out", type=Path, default=None,
                   help="markdown file, the JSON beside it (default results/hopper/accuracy/diagnosis.md)")
    a = p.parse_args(argv)
    if a.max_sims is not None and a.max_sims < 1:
        raise ConfigError(f"max_sims={a.max_sims} is invalid: give at least 1 (or leave it out for all)")
    out = a.out or results_dir() / "hopper" / "accuracy" / "diagnosis.md"
    result = run(a.model, a.dataset, a.part, a.max_sims)
    result.update(machine=machine_info(), command=module_command("neuraldem.scenes.hopper.analysis.diagnosis", argv))
    text = markdown(result)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    atomic_write_json(out.with_suffix(".json"), result)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
