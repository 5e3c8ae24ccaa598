"""Build a shipped pretrained model from a trained checkpoint (what `neuraldem predict` loads).

    python -m neuraldem.pretrained.build --ckpt RUN/checkpoints/last.ckpt --name hopper_small
    python -m neuraldem.pretrained.build --ckpt FB_RUN/checkpoints/best.ckpt --name fb_small
    python -m neuraldem.pretrained.build --name fb_small --refresh-field   # after a change of the bed rollouts

Writes `<out>/<name>/` (default: the package's pretrained folder): `field.pt` (the checkpoint without optimizer
state), `gp.npz` (the scalar Gaussian process fitted on the runs the field model trained and validated on, as
arrays that numpy answers with), for a fluidized bed `states.npz` (the first states of its rollouts,
`build_fb.py`), and `meta.json`: the training data (dataset, SHA-256 of its manifest, the run ids of each
part), the config, the test errors of the field model, the GP and the constant on the checkpoint's held-out
test runs (hopper: scored by the same function as every hopper table; bed: along the path `predict` takes,
beside CFD-DEM's own spread), the trained ranges, answers at probe points, and the rebuild commands.
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
from neuraldem.paths import data_dir

PROBES = [{"alpha": 10.0, "mu_s": 0.2, "mu_r": 0.05}, {"alpha": 35.0, "mu_s": 0.5, "mu_r": 0.2},
          {"alpha": 55.0, "mu_s": 0.8, "mu_r": 0.4}]
PROBE_TIME_STRIDE = 4  # the field model's probe answers use every 4th time (fast enough for the tests)
KEEP = ("state_dict", "hyper_parameters", "pytorch-lightning_version", "global_step", "epoch")


def strip_checkpoint(ckpt: Path, out: Path) -> None:
    """The weights and what rebuilds the module, without optimizer states and loop counters."""
    from neuraldem.eval.checkpoints import read_checkpoint

    raw = read_checkpoint(ckpt).raw  # the process's one read of it
    torch.save({k: raw[k] for k in KEEP if k in raw}, out)


def training_inputs(ckpt: Path, kind: str, dataset: Path | None) -> tuple[dict[str, Any], Path, Manifest]:
    """A checkpoint's metadata (of scene `kind`, else refused with the command that trains one), its dataset
    dir (default: <data dir>/datasets/<its data name>) and that dataset's manifest."""
    from neuraldem.eval.checkpoints import read_checkpoint, require_kind

    meta = read_checkpoint(ckpt).metadata
    require_kind(meta, kind, Path(ckpt), "building a shipped model")
    dataset = dataset or data_dir() / "datasets" / meta["data_name"]
    return meta, dataset, Manifest.load(dataset)


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
    from neuraldem.models.scalar_baselines import gp_answers
    from neuraldem.scenes.hopper.whatif import field_answer

    out = []
    for point, a in zip(PROBES, gp_answers(gp, PROBES), strict=True):
        f = field_answer(module.net, module.metadata, point, settings, time_stride=PROBE_TIME_STRIDE)
        out.append({"parameters": point, "gp_mean": a.mean, "field_summary": f.summary,
                    "field_time_stride": PROBE_TIME_STRIDE})
    return out


def build_record(ckpt: Path, name: str, kind: str, folder: Path, files: dict[str, str], description: str,
                 inputs: list[str], trained_range: dict[str, list[float]], training_data: dict[str, Any],
                 extra: dict[str, Any], build_flags: str = "") -> dict[str, Any]:
    """meta.json of a shipped model: what its files are (with checksums), what it was trained on and with,
    what it scored, and how to rebuild it."""
    from neuraldem.eval.checkpoints import read_checkpoint

    checkpoint = read_checkpoint(ckpt).raw
    hp = checkpoint.get("hyper_parameters", {})
    overrides = run_overrides(Path(ckpt))
    return {
        "name": name, "kind": kind, "description": description, "inputs": inputs, "trained_range": trained_range,
        "files": {role: {"file": f, "sha256": digest(folder / f), "bytes": (folder / f).stat().st_size}
                  for role, f in files.items()},
        "training_data": training_data,
        "config": {"net": hp.get("net"), "optimizer": hp.get("optimizer"), "scheduler": hp.get("scheduler"),
                   "global_step": int(checkpoint.get("global_step", -1)), "train_overrides": overrides},
        **extra,
        "rebuild": [f"neuraldem train {' '.join(overrides)}",
                    f"python -m neuraldem.pretrained.build --ckpt <that run>/checkpoints/{Path(ckpt).name} "
                    f"--name {name}{' ' + build_flags if build_flags else ''}"],
        "built_from": {"checkpoint": str(Path(ckpt).resolve()), "commit": commit(),
                       "date_utc": datetime.now(UTC).isoformat(timespec="seconds")},
    }


def build_hopper(ckpt: Path, name: str, out_root: Path, dataset: Path | None) -> Path:
    from neuraldem.eval.checkpoints import read_checkpoint
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess
    from neuraldem.scenes.hopper.baselines import baseline_inputs, fit_baseline
    from neuraldem.scenes.hopper.evaluation import evaluate_checkpoint
    from neuraldem.scenes.hopper.scoring import dataset_metric_settings

    meta, dataset, m = training_inputs(ckpt, "hopper", dataset)
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
    info = build_record(
        ckpt, name, "hopper", folder, {"field": "field.pt", "gp": "gp.npz"},
        description=f"hopper field model ({sum(v.numel() for v in module.net.parameters()) / 1e6:.2f}M "
                    f"parameters) and scalar GP, trained on {len(ids.get('train', []))} {meta['data_name']} "
                    f"LIGGGHTS runs ({len(ids.get('val', []))} for validation)",
        inputs=inputs,
        trained_range={n: [float(lo), float(hi)] for n, lo, hi in zip(inputs, gp.lo, gp.hi, strict=True)},
        training_data={"dataset": meta["data_name"], "manifest_sha256": digest(dataset / MANIFEST_NAME),
                       "split": meta["split"], "run_ids": ids},
        extra={"conditioning": meta["conditioning"], "metric_settings": settings.as_dict(), "scene": meta["scene"],
               "test_errors": {"n_test_runs": len(result["simulations"]),
                               "runs": [s["sim_id"] for s in result["simulations"]], **test_errors},
               "probes": probe_answers(gp, module, settings)})  # scikit-learn's answers: the arrays must match
    atomic_write_json(folder / "meta.json", info)
    return folder


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p: argparse.ArgumentParser = doc_parser("neuraldem.pretrained.build", __doc__)
    p.add_argument("--ckpt", type=Path, default=None,
                   help="a hopper or fluidized-bed checkpoint written by neuraldem train")
    p.add_argument("--name", required=True, help="the model's name (its folder)")
    p.add_argument("--refresh-field", action="store_true",
                   help="fluidized bed, no --ckpt: rerun the shipped model's field answers (test rows, probe) "
                        "after a change of the rollout code, keeping its files and the stored CFD-DEM answers")
    p.add_argument("--rollout-noise", type=float, default=None,
                   help="with --refresh-field: rollouts read each state + noise of this many times the model's "
                        "one-step error (model.stability.rollout_noise), written into field.pt")
    p.add_argument("--advection-correction", type=float, default=None,
                   help="with --refresh-field: the mixing advection's flux correction in [0, 1] "
                        "(model.stability.advection_correction), written into field.pt")
    p.add_argument("--out", type=Path, default=Path(__file__).parent, help="folder of shipped models")
    p.add_argument("--dataset", type=Path, default=None, help="dataset dir (default: the checkpoint's)")
    p.add_argument("--lacey-time", type=float, default=1.0,
                   help="fluidized bed: the time [s] of the Lacey-index answer (default 1)")
    args = p.parse_args(argv)
    if args.refresh_field:
        if args.ckpt is not None:
            p.error("--refresh-field reruns a shipped model's answers: give --name only, not --ckpt")
        from neuraldem.pretrained.build_fb import refresh_field_answers

        options = {k: v for k, v in (("rollout_noise", args.rollout_noise),
                                     ("advection_correction", args.advection_correction)) if v is not None}
        meta = refresh_field_answers(args.out / args.name, rollout_options=options)
        change = meta["refreshed"][-1]["field_model_errors_before"]
        print(f"refreshed {args.out / args.name}/meta.json: field-model test errors {change} -> "
              f"{meta['test_errors']['field model']}")
        return 0
    if args.ckpt is None:
        p.error("--ckpt is required (or --refresh-field for a shipped fluidized-bed model)")
    if args.rollout_noise is not None or args.advection_correction is not None:
        p.error("--rollout-noise / --advection-correction go with --refresh-field (build first, then set them)")
    from neuraldem.eval.checkpoints import read_checkpoint

    kind = read_checkpoint(args.ckpt).metadata.get("kind")
    if kind == "fluidized_bed":
        from neuraldem.pretrained.build_fb import build_fluidized_bed

        folder = build_fluidized_bed(args.ckpt, args.name, args.out, args.dataset, args.lacey_time)
    else:
        folder = build_hopper(args.ckpt, args.name, args.out, args.dataset)
    sizes = ", ".join(f"{f.name} {f.stat().st_size / 1e6:.2f} MB" for f in sorted(folder.iterdir()))
    print(f"wrote {folder} ({sizes})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
