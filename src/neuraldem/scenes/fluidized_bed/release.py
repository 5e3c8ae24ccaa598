"""The fluidized bed's shipped model (`neuraldem release fluidized_bed ckpt=... name=...`; `predict` loads it).

Files: `field.pt` (the checkpoint without optimizer state), `gp.npz` (a GP on the inlet velocity per answer,
fitted on the training and validation runs), `states.npz` (snapshot 1 of one training trajectory per training
velocity: where a what-if rollout starts) and `meta.json`. The test errors in meta.json are measured along the
path `predict` takes: for each held-out CFD-DEM run, a rollout from the shipped state nearest in velocity,
scored with `whatif.bed_answers`, beside the GP, the training mean and the solver's own spread (CFD-DEM at the
same velocity from another packing).
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from itertools import permutations
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.errors import ConfigError, DataError
from neuraldem.pretrained.card import write_card

ERROR_UNITS = {"bed_height": ("bed_height_mae_mm", 1000.0), "bubble_fraction": ("bubble_fraction_mae_pp", 100.0),
               "lacey": ("lacey_mae", 1.0)}
PROBE_VELOCITY_SHARES = (0.0, 0.5, 1.0)  # probe points: trained range lo, middle, hi


def split_records(m: Manifest, meta: dict[str, Any]) -> dict[str, list[SimRecord]]:
    """The runs of each part as the checkpoint trained on them: its recorded ids, or (checkpoints written
    before they were recorded) the manifest's split with the training part cut to the recorded velocities."""
    usable = {r.sim_id: r for r in m.usable()}
    ids = meta.get("split_ids")
    if ids is None:
        ids = {part: m.split_ids(meta["split"], part) for part in ("train", "val", "test")}
        trained = np.array(meta.get("train_velocities", []), dtype=np.float64)
        ids["train"] = [i for i in ids["train"] if i in usable and trained.size and np.min(
            np.abs(trained - float(usable[i].params["inlet_velocity"]))) < 1e-9]
    missing = [i for part in ids.values() for i in part if i not in usable]
    if missing:
        raise DataError(f"{m.name}: runs {missing[:5]} the checkpoint used are not usable in this dataset")
    return {part: [usable[i] for i in part_ids] for part, part_ids in ids.items()}


def errors(pred: list[dict[str, float]], truth: list[dict[str, float]]) -> dict[str, float]:
    """Mean absolute error per answer, in the units a user reads (mm, percentage points, Lacey index)."""
    out = {}
    for key, (name, scale) in ERROR_UNITS.items():
        d = [abs(p[key] - t[key]) for p, t in zip(pred, truth, strict=True)]
        out[name] = float(scale * np.mean(d)) if d else float("nan")
    out["n_runs"] = len(truth)
    return out


def seed_floor(test: list[SimRecord], answers: dict[str, dict[str, float]]) -> dict[str, float] | None:
    """CFD-DEM at the same velocity from another packing, as the 'prediction' of each held-out run."""
    by_velocity: dict[float, list[str]] = defaultdict(list)
    for r in test:
        by_velocity[round(float(r.params["inlet_velocity"]), 9)].append(r.sim_id)
    pairs = [(a, b) for ids in by_velocity.values() for a, b in permutations(ids, 2)]
    if not pairs:
        return None
    return errors([answers[a] for a, _ in pairs], [answers[b] for _, b in pairs])


def build_fluidized_bed(ckpt: Path, name: str, out_root: Path, dataset: Path | None, lacey_time: float = 1.0,
                        progress: bool = True, reuse_test: bool = False) -> Path:
    from tqdm import tqdm

    from neuraldem.data.integrity import digest
    from neuraldem.data.manifest import MANIFEST_NAME
    from neuraldem.data.schema import atomic_write_json
    from neuraldem.eval.checkpoints import read_checkpoint
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess, ConstantBaseline, GaussianProcessBaseline
    from neuraldem.pretrained.building import build_record, read_test_split, strip_checkpoint, training_inputs
    from neuraldem.scenes.fluidized_bed.analysis.metric_settings import BedMetricSettings
    from neuraldem.scenes.fluidized_bed.whatif import (
        TARGET_RANGE,
        TARGETS,
        AnswerWindow,
        InitialStates,
        field_answer,
        file_answers,
    )

    meta, dataset, m = training_inputs(ckpt, "fluidized_bed", dataset)
    reads = read_test_split(dataset, ckpt, name, reuse_test)
    parts = split_records(m, meta)
    fit_runs = parts.get("train", []) + parts.get("val", [])
    test = parts.get("test", [])
    duration = float(m.parameters["duration"])
    if not 0 < lacey_time <= duration:
        raise DataError(f"lacey_time={lacey_time:g} must lie in (0, {duration:g}] s, the trajectories' duration")
    folder = out_root / name
    folder.mkdir(parents=True, exist_ok=True)
    strip_checkpoint(ckpt, folder / "field.pt")
    module = read_checkpoint(folder / "field.pt").module("fluidized_bed", "cpu", "build")
    window = AnswerWindow(duration, float(lacey_time), module.norm.dt)
    settings = BedMetricSettings.from_config(m.parameters.get("metrics"), f"{dataset} metrics")

    truth = {r.sim_id: file_answers(dataset / str(r.file), settings, window)[0] for r in fit_runs + test}
    x = np.array([[float(r.params["inlet_velocity"])] for r in fit_runs])
    y = {t: np.array([truth[r.sim_id][t] for r in fit_runs]) for t in TARGETS}
    gp = GaussianProcessBaseline(["inlet_velocity"], targets=TARGETS, target_range=TARGET_RANGE).fit(x, y)
    ArrayGaussianProcess.from_fitted(gp).save_npz(folder / "gp.npz")
    constant = ConstantBaseline(["inlet_velocity"], targets=TARGETS, target_range=TARGET_RANGE).fit(x, y)

    firsts: dict[float, SimRecord] = {}
    for r in parts.get("train", []):  # one state per training velocity (its first packing)
        firsts.setdefault(float(r.params["inlet_velocity"]), r)
    states = InitialStates.from_files([dataset / str(r.file) for _, r in sorted(firsts.items())])
    states.save_npz(folder / "states.npz")

    rows = []
    for r in tqdm(test, desc="test rollouts", unit="run", disable=not progress):
        v = float(r.params["inlet_velocity"])
        f = field_answer(module, states, v, settings, window)
        rows.append({"sim_id": r.sim_id, "inlet_velocity": v, "cfd_dem": truth[r.sim_id], "field model": f.summary,
                     "field_start": f.start, "rollout_seconds": f.seconds,
                     "gp": gp.predict(np.array([[v]]))[0].mean, "constant": constant.predict(np.array([[v]]))[0].mean})
    cfd = [row["cfd_dem"] for row in rows]
    test_errors: dict[str, Any] = {"n_test_runs": len(rows), "runs": rows}
    for who in ("field model", "gp", "constant"):
        test_errors[who] = errors([row[who] for row in rows], cfd)
    floor = seed_floor(test, truth)
    if floor is not None:
        test_errors["seed floor"] = floor

    gp_arrays = ArrayGaussianProcess.load_npz(folder / "gp.npz")
    lo, hi = float(gp_arrays.lo[0]), float(gp_arrays.hi[0])
    probe_v = [lo + s * (hi - lo) for s in PROBE_VELOCITY_SHARES]
    mid = field_answer(module, states, probe_v[1], settings, window)
    probes = [{"parameters": {"inlet_velocity": v}, "gp_mean": a.mean}
              for v, a in zip(probe_v, gp.predict(np.array([[v] for v in probe_v])), strict=True)]
    probes[1]["field_summary"] = mid.summary

    info = build_record(
        ckpt, name, "fluidized_bed", folder, {"field": "field.pt", "gp": "gp.npz", "states": "states.npz"},
        description=f"fluidized-bed field model ({sum(p.numel() for p in module.net.parameters()) / 1e6:.2f}M "
                    f"parameters) and scalar GP, trained on {len(parts.get('train', []))} {m.name} CFD-DEM "
                    f"trajectories ({len(parts.get('val', []))} for validation)",
        inputs=["inlet_velocity"], trained_range={"inlet_velocity": [lo, hi]},
        training_data={"dataset": m.name, "manifest_sha256": digest(dataset / MANIFEST_NAME), "split": meta["split"],
                       "run_ids": {p: [r.sim_id for r in rs] for p, rs in parts.items()}},
        extra={"asked_range": {n: [float(v) for v in r] for n, r in (m.parameters.get("ranges") or {}).items()
                               if n == "inlet_velocity"},
               "conditioning": meta["conditioning"], "metric_settings": settings.__dict__ | {
                   "lacey_block": list(settings.lacey_block)},
               "answer_window": window.as_dict(), "scene": m.scene, "test_errors": test_errors, "test_reads": reads,
               "probes": probes,
               "initial_states": [f"{i} ({v:.4g} m/s)" for i, v in zip(states.sim_ids, states.velocities,
                                                                         strict=True)]},
        build_flags=f"lacey_time={lacey_time:g}")
    atomic_write_json(folder / "meta.json", info)
    write_card(folder)
    return folder


ROLLOUT_OPTIONS = ("rollout_noise", "advection_correction")  # the rollout options a shipped model may store


def set_rollout_options(field: Path, options: dict[str, float]) -> dict[str, float]:
    """Write rollout options (`rollout.rollout_noise` / `rollout.advection_correction`, chosen on validation) into
    a shipped field checkpoint's stability, so every path that rolls the shipped model out (`predict fb`, the
    explorer, the benches, `evaluate ckpt=<field.pt>`) uses them without a flag of its own. Checked before the
    file is touched: the values' ranges and, for noise, that the checkpoint holds the running one-step error.
    Returns the checkpoint's rollout options after the change (all of them, the ones not given as they were)."""
    import torch

    from neuraldem.eval.checkpoints import read_checkpoint
    from neuraldem.scenes.fluidized_bed.surrogate.options import BedStability, RolloutOptions
    from neuraldem.scenes.fluidized_bed.surrogate.rollout import perturbation_std

    unknown = sorted(set(options) - set(ROLLOUT_OPTIONS))
    if unknown:
        raise DataError(f"{field}: {unknown[0]} is not a rollout option of a shipped model (known: {ROLLOUT_OPTIONS})")
    RolloutOptions(**options)  # their ranges: one line naming the key
    checkpoint = read_checkpoint(field)  # one read: its raw dict for the rewrite, its module for the check
    hp = checkpoint.hyper_parameters  # a copy: the read is shared within the process
    stability = dict(hp.get("stability") or {})
    stability.update({k: float(v) for k, v in options.items()})
    checked = BedStability.from_config(stability)
    module = checkpoint.module("fluidized_bed", "cpu", "setting rollout options")
    perturbation_std(module, checked.rollout_noise, "cpu")
    hp["stability"] = stability
    tmp = field.with_suffix(".tmp")
    torch.save({**checkpoint.raw, "hyper_parameters": hp}, tmp)
    tmp.replace(field)
    return {k: float(getattr(checked, k)) for k in ROLLOUT_OPTIONS}


def refresh_field_answers(folder: Path, progress: bool = True,
                          rollout_options: dict[str, float] | None = None) -> dict[str, Any]:
    """Re-run a shipped bed model's field answers (its test rows and the probe) after the rollout code changed,
    keeping its files, the GP and the CFD-DEM answers stored with each test row: the rollouts start from the
    shipped states, so no dataset is needed. The field model's test errors are recomputed against the stored
    CFD-DEM answers and the refresh is recorded in meta.json (`refreshed`). `rollout_options` are written into
    field.pt first (`set_rollout_options`; its checksum in meta.json follows) and recorded in meta.json."""
    import json
    from datetime import UTC, datetime

    from tqdm import tqdm

    from neuraldem.data.schema import atomic_write_json
    from neuraldem.eval.checkpoints import read_checkpoint
    from neuraldem.pretrained.building import commit
    from neuraldem.scenes.fluidized_bed.analysis.metric_settings import BedMetricSettings
    from neuraldem.scenes.fluidized_bed.surrogate.options import RolloutOptions
    from neuraldem.scenes.fluidized_bed.whatif import AnswerWindow, InitialStates, field_answer

    path = folder / "meta.json"
    if not path.is_file():
        raise DataError(f"{path} is missing: {folder} is not a shipped model (build it with ckpt=)")
    meta = json.loads(path.read_text())
    if meta.get("kind") != "fluidized_bed":
        raise DataError(f"{path}: kind {meta.get('kind')!r}; refresh_field= is for fluidized-bed models")
    field = folder / meta["files"]["field"]["file"]
    if rollout_options:
        from neuraldem.data.integrity import digest

        meta["rollout_options"] = set_rollout_options(field, rollout_options)
        meta["files"]["field"].update(sha256=digest(field), bytes=field.stat().st_size)
        keys = " ".join(RolloutOptions(**meta["rollout_options"]).overrides())
        kept = [c for c in meta.get("rebuild", []) if "refresh_field=" not in c and "--refresh-field" not in c]
        meta["rebuild"] = [*kept, f"neuraldem release fluidized_bed name={meta['name']} refresh_field=true {keys}"]
    module = read_checkpoint(field).module("fluidized_bed", "cpu", "refresh")
    states = InitialStates.load_npz(folder / meta["files"]["states"]["file"])
    settings = BedMetricSettings.from_config(meta["metric_settings"], f"{path} metric_settings")
    window = AnswerWindow.from_dict(meta["answer_window"])
    before = dict(meta["test_errors"]["field model"])
    rows = meta["test_errors"]["runs"]
    for row in tqdm(rows, desc="test rollouts", unit="run", disable=not progress):
        f = field_answer(module, states, float(row["inlet_velocity"]), settings, window)
        row.update({"field model": f.summary, "field_start": f.start, "rollout_seconds": f.seconds})
    meta["test_errors"]["field model"] = errors([r["field model"] for r in rows], [r["cfd_dem"] for r in rows])
    probe = next(p for p in meta["probes"] if "field_summary" in p)
    probe["field_summary"] = field_answer(module, states, float(probe["parameters"]["inlet_velocity"]), settings,
                                          window).summary
    meta.setdefault("refreshed", []).append({
        "what": "field-model answers (test rows and probe) rerun with the rollout code of this commit"
                + (f" and rollout options {rollout_options}" if rollout_options else ""),
        "field_model_errors_before": before, "commit": commit(),
        "date_utc": datetime.now(UTC).isoformat(timespec="seconds")})
    atomic_write_json(path, meta)
    write_card(folder)
    return meta


def add_options(p: argparse.ArgumentParser) -> None:
    from neuraldem.scenes.fluidized_bed.surrogate.options import add_arguments

    p.add_argument("--lacey-time", type=float, default=1.0,
                   help="fluidized bed: the time [s] of the Lacey-index answer (default 1)")
    p.add_argument("--refresh-field", action="store_true",
                   help="fluidized bed, no ckpt=: rerun the shipped model's field answers (test rows, probe) after "
                        "a change of the rollout code, keeping its files and the stored CFD-DEM answers")
    add_arguments(p, ROLLOUT_OPTIONS, default="as trained; with refresh_field=true: written into field.pt")


def release(args: argparse.Namespace) -> str:
    from neuraldem.scenes.fluidized_bed.surrogate.options import RolloutOptions

    options = RolloutOptions.from_args(args).given()
    if args.refresh_field:
        if args.ckpt is not None:
            raise ConfigError("refresh_field=true reruns a shipped model's answers: give name= only, not ckpt=")
        from neuraldem import pretrained

        folder = args.out / args.name if args.out is not None else pretrained.load(args.name, "fluidized_bed").folder
        meta = refresh_field_answers(folder, rollout_options=options)
        change = meta["refreshed"][-1]["field_model_errors_before"]
        return (f"refreshed {folder}/meta.json: field-model test errors {change} -> "
                f"{meta['test_errors']['field model']}")
    if args.ckpt is None:
        raise ConfigError("ckpt= is required (or refresh_field=true for a shipped fluidized-bed model)")
    if options:
        raise ConfigError(f"{' / '.join(f'rollout.{k}=' for k in ROLLOUT_OPTIONS)} go with refresh_field=true "
                          "(build first, then set them)")
    folder = build_fluidized_bed(args.ckpt, args.name, args.out, args.dataset, args.lacey_time,
                                 reuse_test=args.reuse_test)
    sizes = ", ".join(f"{f.name} {f.stat().st_size / 1e6:.2f} MB" for f in sorted(folder.iterdir()))
    return f"wrote {folder} ({sizes})"
