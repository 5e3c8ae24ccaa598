"""Build a shipped pretrained hopper model from a trained checkpoint (what `neuraldem predict` loads).

    python -m neuraldem.pretrained.build --ckpt RUN/checkpoints/last.ckpt --name hopper_small

Writes `<out>/<name>/` (default: the package's pretrained folder): `field.pt` (the checkpoint without optimizer
state), `gp.npz` (the scalar Gaussian process fitted on the runs the field model trained and validated on, as
arrays that numpy answers with) and `meta.json`: the training data (dataset, SHA-256 of its manifest, the run
ids of each part), the config, the test errors of the field model, the GP and the constant on the checkpoint's
held-out test runs (scored by the same function as every hopper table), the trained ranges, answers at probe
points, and the rebuild commands.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch
import yaml

from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.data.integrity import digest
from neuraldem.data.manifest import MANIFEST_NAME, Manifest
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import DataError
from neuraldem.paths import data_dir

PROBES = [{"alpha": 10.0, "mu_s": 0.2, "mu_r": 0.05}, {"alpha": 35.0, "mu_s": 0.5, "mu_r": 0.2},
          {"alpha": 55.0, "mu_s": 0.8, "mu_r": 0.4}]
PROBE_TIME_STRIDE = 4  # the field model's probe answers use every 4th time (fast enough for the tests)
KEEP = ("state_dict", "hyper_parameters", "pytorch-lightning_version", "global_step", "epoch")


def strip_checkpoint(ckpt: Path, out: Path) -> None:
    """The weights and what rebuilds the module, without optimizer states and loop counters."""
    raw = torch.load(ckpt, map_location="cpu", weights_only=False)
    torch.save({k: raw[k] for k in KEEP if k in raw}, out)


def run_overrides(ckpt: Path) -> list[str]:
    path = ckpt.parent.parent / ".hydra" / "overrides.yaml"
    return list(yaml.safe_load(path.read_text())) if path.is_file() else []


def commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def probe_answers(gp: Any, module: Any, settings: Any) -> list[dict[str, Any]]:
    from neuraldem.scenes.hopper.whatif import field_answer, gp_answers

    out = []
    for point, a in zip(PROBES, gp_answers(gp, PROBES), strict=True):
        f = field_answer(module.net, module.metadata, point, settings, time_stride=PROBE_TIME_STRIDE)
        out.append({"parameters": point, "gp_mean": a.mean, "field_summary": f.summary,
                    "field_time_stride": PROBE_TIME_STRIDE})
    return out


def build_hopper(ckpt: Path, name: str, out_root: Path, dataset: Path | None) -> Path:
    from neuraldem.eval.checkpoints import read_checkpoint
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess
    from neuraldem.scenes.hopper.baselines import baseline_inputs, fit_baseline
    from neuraldem.scenes.hopper.evaluation import evaluate_checkpoint
    from neuraldem.scenes.hopper.scoring import dataset_metric_settings

    checkpoint = read_checkpoint(ckpt)
    meta = checkpoint.metadata
    if meta.get("kind") != "hopper":
        raise DataError(f"{ckpt} is a {meta.get('kind')!r} checkpoint; this builds hopper models")
    dataset = dataset or data_dir() / "datasets" / meta["data_name"]
    m = Manifest.load(dataset)
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
    test_errors = {"field model": result["aggregate"],
                   **{k: v["aggregate"] for k, v in result["baselines"].items() if "aggregate" in v}}
    files = {role: {"file": f, "sha256": digest(folder / f), "bytes": (folder / f).stat().st_size}
             for role, f in (("field", "field.pt"), ("gp", "gp.npz"))}
    hp = checkpoint.hyper_parameters
    overrides = run_overrides(Path(ckpt))
    info = {
        "name": name, "kind": "hopper",
        "description": f"hopper field model ({sum(v.numel() for v in module.net.parameters()) / 1e6:.2f}M "
                       f"parameters) and scalar GP, trained on {len(ids.get('train', []))} {meta['data_name']} "
                       f"LIGGGHTS runs ({len(ids.get('val', []))} for validation)",
        "inputs": inputs, "conditioning": meta["conditioning"],
        "trained_range": {n: [float(lo), float(hi)] for n, lo, hi in zip(inputs, gp.lo, gp.hi, strict=True)},
        "files": files,
        "training_data": {"dataset": meta["data_name"], "manifest_sha256": digest(dataset / MANIFEST_NAME),
                          "split": meta["split"], "run_ids": ids},
        "config": {"net": hp.get("net"), "optimizer": hp.get("optimizer"), "scheduler": hp.get("scheduler"),
                   "global_step": int(torch.load(ckpt, map_location="cpu", weights_only=False)["global_step"]),
                   "train_overrides": overrides},
        "metric_settings": settings.as_dict(), "scene": meta["scene"],
        "test_errors": {"n_test_runs": len(result["simulations"]), "runs": [s["sim_id"] for s in result["simulations"]],
                        **test_errors},
        "probes": probe_answers(gp, module, settings),  # scikit-learn's answers: the shipped arrays must match
        "rebuild": [f"neuraldem train {' '.join(overrides)}",
                    f"python -m neuraldem.pretrained.build --ckpt <that run>/checkpoints/{Path(ckpt).name} "
                    f"--name {name}"],
        "built_from": {"checkpoint": str(Path(ckpt).resolve()), "commit": commit(),
                       "date_utc": datetime.now(UTC).isoformat(timespec="seconds")},
    }
    atomic_write_json(folder / "meta.json", info)
    return folder


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p: argparse.ArgumentParser = doc_parser("neuraldem.pretrained.build", __doc__)
    p.add_argument("--ckpt", type=Path, required=True, help="a hopper checkpoint written by neuraldem train")
    p.add_argument("--name", required=True, help="the model's name (its folder)")
    p.add_argument("--out", type=Path, default=Path(__file__).parent, help="folder of shipped models")
    p.add_argument("--dataset", type=Path, default=None, help="dataset dir (default: the checkpoint's)")
    args = p.parse_args(argv)
    folder = build_hopper(args.ckpt, args.name, args.out, args.dataset)
    sizes = ", ".join(f"{f.name} {f.stat().st_size / 1e6:.2f} MB" for f in sorted(folder.iterdir()))
    print(f"wrote {folder} ({sizes})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
