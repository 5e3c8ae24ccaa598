"""The hopper's shipped model: the field model, the scalar GP fitted on the runs the field model trained and
validated on (as arrays numpy answers with), and meta.json with the test errors of the field model, the GP and
the constant on the checkpoint's held-out test runs (scored by the same function as every hopper table), the
trained ranges and answers at probe points.

    neuraldem release ckpt=RUN/checkpoints/last.ckpt name=hopper_small
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import Any

from neuraldem.data.integrity import digest
from neuraldem.data.manifest import MANIFEST_NAME
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import ConfigError, DataError
from neuraldem.pretrained.building import build_record, read_test_split, strip_checkpoint, training_inputs
from neuraldem.pretrained.card import write_card

PROBES = [{"alpha": 10.0, "mu_s": 0.2, "mu_r": 0.05}, {"alpha": 35.0, "mu_s": 0.5, "mu_r": 0.2},
          {"alpha": 55.0, "mu_s": 0.8, "mu_r": 0.4}]
PROBE_TIME_STRIDE = 4  # the field model's probe answers use every 4th time (fast enough for the tests)
PROBE_SHARES = (1 / 6, 1 / 2, 5 / 6)  # probes of a model trained on other ranges: these shares of each range


def probe_points(trained_range: dict[str, list[float]]) -> list[dict[str, float]]:
    """The fixed PROBES where the model was trained on them, else points at PROBE_SHARES of each trained range."""
    inside = all(set(p) == set(trained_range) and all(trained_range[n][0] <= v <= trained_range[n][1]
                                                      for n, v in p.items()) for p in PROBES)
    if inside:
        return PROBES
    return [{n: lo + share * (hi - lo) for n, (lo, hi) in trained_range.items()} for share in PROBE_SHARES]


def probe_answers(gp: Any, module: Any, settings: Any, points: list[dict[str, float]]) -> list[dict[str, Any]]:
    """The GP's and the field model's answers at the probe points (what a test of the released files repeats); a
    field model that sees no material at a probe (barely trained) gets a note instead of numbers."""
    from neuraldem.errors import DataError
    from neuraldem.models.scalar_baselines import gp_answers
    from neuraldem.scenes.hopper.whatif import field_answer

    out = []
    for point, a in zip(points, gp_answers(gp, points), strict=True):
        row: dict[str, Any] = {"parameters": point, "gp_mean": a.mean, "field_time_stride": PROBE_TIME_STRIDE}
        try:
            row["field_summary"] = field_answer(module.net, module.metadata, point, settings,
                                                time_stride=PROBE_TIME_STRIDE).summary
        except DataError as err:
            row["field_summary"], row["field_note"] = {}, str(err)
        out.append(row)
    return out


def build_hopper(ckpt: Path, name: str, out_root: Path, dataset: Path | None, reuse_test: bool = False) -> Path:
    from neuraldem.eval.checkpoints import read_checkpoint
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess
    from neuraldem.scenes.hopper.analysis.baselines import baseline_inputs, fit_baseline
    from neuraldem.scenes.hopper.analysis.evaluation import evaluate_checkpoint
    from neuraldem.scenes.hopper.analysis.scoring import dataset_metric_settings

    meta, dataset, m = training_inputs(ckpt, "hopper", dataset)
    reads = read_test_split(dataset, ckpt, name, reuse_test)
    ids = meta.get("split_ids") or {}
    fit_runs = [m.record(i) for i in ids.get("train", []) + ids.get("val", [])]
    folder = out_root / name
    folder.mkdir(parents=True, exist_ok=True)

    strip_checkpoint(ckpt, folder / "field.pt")
    inputs = baseline_inputs(list(meta["conditioning"]))
    gp = fit_baseline("gp", fit_runs, inputs)
    ArrayGaussianProcess.from_fitted(gp).save_npz(folder / "gp.npz")  # answered with numpy alone
    (folder / "gp.pkl").unlink(missing_ok=True)  # written by earlier versions

    with tempfile.TemporaryDirectory() as tmp:  # scored on the checkpoint's own test runs
        result = evaluate_checkpoint(ckpt, Path(tmp), dataset.parent, dataset, vtk=False, progress=True)
    settings = dataset_metric_settings(m)
    module = read_checkpoint(folder / "field.pt").module("hopper", "cpu", "build")
    trained_range = {n: [float(lo), float(hi)] for n, lo, hi in zip(inputs, gp.lo, gp.hi, strict=True)}
    test_errors = {"field model": result["aggregate"],
                   **{k: v["aggregate"] for k, v in result["baselines"].items() if "aggregate" in v}}
    info = build_record(
        ckpt, name, "hopper", folder, {"field": "field.pt", "gp": "gp.npz"},
        description=f"hopper field model ({sum(v.numel() for v in module.net.parameters()) / 1e6:.2f}M "
                    f"parameters) and scalar GP, trained on {len(ids.get('train', []))} {meta['data_name']} "
                    f"LIGGGHTS runs ({len(ids.get('val', []))} for validation)",
        inputs=inputs,
        trained_range=trained_range,
        training_data={"dataset": meta["data_name"], "manifest_sha256": digest(dataset / MANIFEST_NAME),
                       "split": meta["split"], "run_ids": ids},
        extra={"asked_range": {n: [float(v) for v in r] for n, r in (m.parameters.get("ranges") or {}).items()
                               if n in inputs},
               "conditioning": meta["conditioning"], "metric_settings": settings.as_dict(), "scene": meta["scene"],
               "test_errors": {"n_test_runs": len(result["simulations"]),
                               "runs": [s["sim_id"] for s in result["simulations"]], **test_errors},
               # the probes: scikit-learn's answers, which the shipped arrays must match
               "probes": probe_answers(gp, module, settings, probe_points(trained_range)), "test_reads": reads})
    atomic_write_json(folder / "meta.json", info)
    export_field(folder)
    return folder


def export_field(folder: Path) -> Path:
    """`field.onnx` beside `field.pt` (what `predict` answers with when ONNX Runtime is installed, without
    importing torch) and the field model's metadata in meta.json (what the answer needs besides the net); the
    export is checked against the torch net at the probe points before it is recorded."""
    import json

    import numpy as np
    import torch

    from neuraldem.eval.checkpoints import checkpoint_net, read_checkpoint
    from neuraldem.models.onnx_runtime import OnnxNet, export_onnx

    checkpoint = read_checkpoint(folder / "field.pt")
    net = checkpoint_net(checkpoint, "hopper", "cpu", "the ONNX export")
    example = net.example_inputs(batch_size=2, n_queries=64, generator=torch.Generator().manual_seed(0))
    path = export_onnx(net, example, ["occupancy", "transport", "residence"], folder / "field.onnx",
                       {"scalars": {0: "times"}, "query_pos": {0: "times", 1: "queries"},
                        **{k: {0: "times", 1: "queries"} for k in ("occupancy", "transport", "residence")}})
    check = net.example_inputs(batch_size=3, n_queries=500, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        want = net(**check)
    got = OnnxNet(path)(**{k: v.numpy() for k, v in check.items()})
    worst = max(float(np.abs(want[k].numpy() - got[k]).max()) for k in got)
    if worst > ONNX_TOLERANCE:
        path.unlink()
        raise DataError(f"{path}: the ONNX export differs from the torch net by {worst:.2g} (> {ONNX_TOLERANCE:g})",
                        "keep runtime=torch for this model")
    meta_path = folder / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta["files"]["onnx"] = {"file": path.name, "sha256": digest(path), "bytes": path.stat().st_size,
                             "max_abs_difference_to_torch": worst}
    meta["field_metadata"] = checkpoint.metadata
    atomic_write_json(meta_path, meta)
    write_card(folder)
    return path


ONNX_TOLERANCE = 1e-3  # largest output difference (model units) an export may have from the torch net


def add_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--onnx-only", action="store_true",
                   help="hopper, no ckpt=: add field.onnx (answers without torch) to an already released model")


def release(args: argparse.Namespace) -> str:
    if args.onnx_only:
        if args.ckpt is not None:
            raise ConfigError("onnx_only=true exports an already released model: give name= only, not ckpt=")
        if not (args.out / args.name / "field.pt").is_file():
            raise ConfigError(f"onnx_only=true: {args.out / args.name} holds no released hopper model",
                              "give name= of a model in out= (default: the shipped models)")
        path = export_field(args.out / args.name)
        return f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB) and its entry in meta.json"
    if args.ckpt is None:
        raise ConfigError("ckpt= is required: the checkpoint to release (e.g. ckpt=RUN/checkpoints/last.ckpt)")
    folder = build_hopper(args.ckpt, args.name, args.out, args.dataset, args.reuse_test)
    sizes = ", ".join(f"{f.name} {f.stat().st_size / 1e6:.2f} MB" for f in sorted(folder.iterdir()))
    return f"wrote {folder} ({sizes})"
