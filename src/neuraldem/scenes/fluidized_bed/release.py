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


def held_out_runs(test_dataset: Path, m: Manifest) -> tuple[Manifest, list[SimRecord]]:
    """The test part of a dataset of held-out runs (`test_dataset=`: new velocities and packings of the training
    dataset's scene, e.g. data=fb_small_heldout), refused when its scene, duration or metric settings differ from
    the training dataset's (its answers would not be the same questions)."""
    held = Manifest.load(test_dataset)
    for what, mine, theirs in (("scene", held.scene, m.scene),
                               ("trajectory duration", held.parameters.get("duration"), m.parameters.get("duration")),
                               ("metric settings", held.parameters.get("metrics"), m.parameters.get("metrics"))):
        if mine != theirs:
            raise DataError(f"{test_dataset}: its {what} differs from the training dataset {m.name}'s, so its runs "
                            "do not test this model's answers", f"use held-out runs of {m.name}'s scene "
                            "(e.g. neuraldem datagen data=fb_small_heldout)")
    usable = {r.sim_id: r for r in held.usable()}
    test = [usable[i] for i in held.split_ids("velocity", "test") if i in usable]
    if not test:
        raise DataError(f"{test_dataset}: no finished run in its test part", "finish it first: neuraldem datagen "
                        f"data={held.name} (resumable)")
    return held, test


def read_results(path: Path, what: str) -> dict[str, Any]:
    import json

    try:
        d = json.loads(Path(path).read_text())
    except (OSError, ValueError) as err:
        raise DataError(f"{path}: not readable as {what} ({type(err).__name__})",
                        f"give the JSON {what} wrote") from None
    return d.get("results", d)


def same_checkpoint(recorded: str | None, ckpt: Path) -> bool:
    """Whether a checkpoint path recorded by another command is `ckpt`: the same path, or a copy of the same bytes
    (fb-select copies the one it chooses)."""
    import filecmp

    if not recorded:
        return False
    other = Path(recorded)
    return other.resolve() == Path(ckpt).resolve() or (
        other.is_file() and Path(ckpt).is_file() and filecmp.cmp(other, ckpt, shallow=False))


def chosen_record(selection: Path, ckpt: Path) -> str:
    """What validation chose, from `report fb-select`'s JSON, which must have chosen this very checkpoint."""
    d = read_results(selection, "report fb-select")
    picked = d.get("selected") or {}
    if not any(same_checkpoint(picked.get(k), ckpt) for k in ("checkpoint", "copied_to")):
        chose = picked.get("copied_to") or picked.get("checkpoint") or "nothing"
        raise DataError(f"{selection}: fb-select chose {chose}, not ckpt={ckpt}",
                        "release the checkpoint the selection chose, or give that selection's JSON")
    rows = d.get("rows", [])
    best = next((r for r in rows if r.get("step") == picked.get("step")), {})
    options = {k: d[k] for k in ("rollout_noise", "advection_correction", "mirror_alternate") if k in d}
    return (f"the checkpoint of step {picked.get('step')} among {len(rows)} (steps {d.get('from_step')} on), by "
            f"`neuraldem report fb-select` on the validation runs and {', '.join(d.get('long_val') or {}) or 'no'} "
            f"long validation trajectory, rollouts of 10x the training horizon under rollout options {options}, "
            f"rollout seeds {d.get('seeds')}: sum of the pooled errors (time mean + std field + Lacey) "
            f"{best.get('sum', float('nan')):.3f} ({d.get('date_utc', '')})")


def stability_record(scan: Path, ckpt: Path) -> tuple[str, list[dict[str, Any]]]:
    """The stability scan (`bench fb_stability`'s JSON, one series of this checkpoint) as the card's line and its
    failed velocities as weak regions."""
    d = read_results(scan, "bench fb_stability")
    series = [x for x in d.get("series", []) if same_checkpoint(x.get("checkpoint"), ckpt)]
    if len(series) != 1:
        raise DataError(f"{scan}: no single series of ckpt={ckpt} in it", "give the scan of this checkpoint")
    points = series[0]["points"]
    velocities = [p["inlet_velocity"] for p in points]
    devs = [p["bed_deviation_pct"] for p in points if p.get("bed_checked")]
    failed = [p for p in points if not p.get("ok", False)]
    weak = [{"parameters": {"inlet_velocity": p["inlet_velocity"]},
             "note": p.get("failure") or p.get("bed_failure") or p.get("divergence") or "failed"} for p in failed]
    if not devs:
        return f"{len(points)} velocities, {len(failed)} failed", weak
    line = (f"{len(points)} inlet velocities {min(velocities):.4g} .. {max(velocities):.4g} m/s, {d.get('steps')} "
            f"steps each (rollout options noise {d.get('rollout_noise')}, correction "
            f"{d.get('advection_correction')}, mirror-alternating {d.get('mirror_alternate')}): {len(failed)} failed "
            f"(divergence, solid-volume drift beyond {d.get('drift_limit_pct')} % or a time-mean bed height beyond "
            f"{d.get('bed_limit_pct')} % of CFD-DEM's); bed heights {min(devs):+.1f} to {max(devs):+.1f} % from "
            "CFD-DEM's (`neuraldem bench fb_stability`)")
    return line, weak


def build_fluidized_bed(ckpt: Path, name: str, out_root: Path, dataset: Path | None, lacey_time: float = 1.0,
                        progress: bool = True, reuse_test: bool = False,
                        rollout_options: dict[str, Any] | None = None, test_dataset: Path | None = None,
                        selection: Path | None = None, stability_scan: Path | None = None) -> Path:
    """The model folder `out_root/name`. `rollout_options` (chosen on validation) are written into its field.pt
    before anything is scored, so its test errors are those of the rollouts `predict` runs. `test_dataset`: score
    the held-out runs of that dataset (`held_out_runs`) instead of the test part of the checkpoint's split; its test
    runs are the ones read (and recorded) then. `selection` (fb-select's JSON, which must have chosen `ckpt`) and
    `stability_scan` (fb_stability's JSON of `ckpt`) go into the card: what validation chose, the scan, its weak
    regions."""
    from tqdm import tqdm

    from neuraldem.data.integrity import digest
    from neuraldem.data.manifest import MANIFEST_NAME
    from neuraldem.data.schema import atomic_write_json
    from neuraldem.eval.checkpoints import read_checkpoint
    from neuraldem.models.scalar_baselines import ArrayGaussianProcess, ConstantBaseline, GaussianProcessBaseline
    from neuraldem.pretrained.building import build_record, read_test_split, strip_checkpoint, training_inputs
    from neuraldem.scenes.fluidized_bed.analysis.metric_settings import BedMetricSettings
    from neuraldem.scenes.fluidized_bed.surrogate.options import RolloutOptions
    from neuraldem.scenes.fluidized_bed.whatif import (
        TARGET_RANGE,
        TARGETS,
        AnswerWindow,
        InitialStates,
        field_answer,
        file_answers,
    )

    meta, dataset, m = training_inputs(ckpt, "fluidized_bed", dataset)
    parts = split_records(m, meta)
    held = None
    if test_dataset is not None:
        held, held_test = held_out_runs(test_dataset, m)
    if rollout_options:
        RolloutOptions(**rollout_options)  # checked before anything is read or written
    chosen = chosen_record(selection, ckpt) if selection is not None else None
    scanned = stability_record(stability_scan, ckpt) if stability_scan is not None else None
    duration = float(m.parameters["duration"])
    if not 0 < lacey_time <= duration:
        raise DataError(f"lacey_time={lacey_time:g} must lie in (0, {duration:g}] s, the trajectories' duration")
    reads = read_test_split(dataset if held is None else test_dataset, ckpt, name, reuse_test)  # every check passed
    fit_runs = parts.get("train", []) + parts.get("val", [])
    test = parts.get("test", []) if held is None else held_test
    test_dir = dataset if held is None else test_dataset
    folder = out_root / name
    folder.mkdir(parents=True, exist_ok=True)
    strip_checkpoint(ckpt, folder / "field.pt")
    applied = set_rollout_options(folder / "field.pt", rollout_options) if rollout_options else None
    module = read_checkpoint(folder / "field.pt").module("fluidized_bed", "cpu", "build")
    window = AnswerWindow(duration, float(lacey_time), module.norm.dt)
    settings = BedMetricSettings.from_config(m.parameters.get("metrics"), f"{dataset} metrics")

    truth = {r.sim_id: file_answers(dataset / str(r.file), settings, window)[0] for r in fit_runs}
    # the test runs' own: a held-out dataset numbers its runs from sim_0000 as well
    test_truth = {r.sim_id: file_answers(test_dir / str(r.file), settings, window)[0] for r in test}
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
        rows.append({"sim_id": r.sim_id, **({"dataset": held.name} if held else {}), "inlet_velocity": v,
                     "cfd_dem": test_truth[r.sim_id], "field model": f.summary,
                     "field_start": f.start, "rollout_seconds": f.seconds,
                     "gp": gp.predict(np.array([[v]]))[0].mean, "constant": constant.predict(np.array([[v]]))[0].mean})
    cfd = [row["cfd_dem"] for row in rows]
    test_errors: dict[str, Any] = {"n_test_runs": len(rows), "runs": rows}
    for who in ("field model", "gp", "constant"):
        test_errors[who] = errors([row[who] for row in rows], cfd)
    floor = seed_floor(test, test_truth)
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
                       "run_ids": {p: [r.sim_id for r in rs] for p, rs in parts.items()},
                       **({"test_dataset": {"dataset": held.name, "manifest_sha256": digest(test_dir / MANIFEST_NAME),
                                            "run_ids": [r.sim_id for r in test]}} if held else {})},
        extra={"asked_range": {n: [float(v) for v in r] for n, r in (m.parameters.get("ranges") or {}).items()
                               if n == "inlet_velocity"},
               "conditioning": meta["conditioning"], "metric_settings": settings.__dict__ | {
                   "lacey_block": list(settings.lacey_block)},
               "answer_window": window.as_dict(), "scene": m.scene, "test_errors": test_errors, "test_reads": reads,
               "probes": probes,
               "initial_states": [f"{i} ({v:.4g} m/s)" for i, v in zip(states.sim_ids, states.velocities,
                                                                         strict=True)],
               **({"rollout_options": applied} if applied else {}), **({"chosen": chosen} if chosen else {}),
               **({"stability": scanned[0], "weak_regions": scanned[1]} if scanned else {})},
        build_flags=" ".join([f"lacey_time={lacey_time:g}", *([f"test_dataset={held.name}"] if held else []),
                              *RolloutOptions(**(rollout_options or {})).overrides()]))
    atomic_write_json(folder / "meta.json", info)
    write_card(folder)
    return folder


# the rollout options a shipped model may store
ROLLOUT_OPTIONS = ("rollout_noise", "advection_correction", "mirror_alternate")


def set_rollout_options(field: Path, options: dict[str, Any]) -> dict[str, Any]:
    """Write rollout options (`rollout.rollout_noise` / `rollout.advection_correction` /
    `rollout.mirror_alternate`, chosen on validation) into a shipped field checkpoint's stability, so every path
    that rolls the shipped model out (`predict fb`, the explorer, the benches, `evaluate ckpt=<field.pt>`) uses
    them without a flag of its own. Checked before the file is touched: the values' ranges and, for noise, that
    the checkpoint holds the running one-step error. Returns the checkpoint's rollout options after the change
    (all of them, the ones not given as they were)."""
    import torch

    from neuraldem.eval.checkpoints import read_checkpoint
    from neuraldem.scenes.fluidized_bed.surrogate.options import BedStability, RolloutOptions
    from neuraldem.scenes.fluidized_bed.surrogate.rollout import perturbation_std

    unknown = sorted(set(options) - set(ROLLOUT_OPTIONS))
    if unknown:
        raise DataError(f"{field}: {unknown[0]} is not a rollout option of a shipped model (known: {ROLLOUT_OPTIONS})")
    given = RolloutOptions(**options).given()  # their ranges: one line naming the key
    checkpoint = read_checkpoint(field)  # one read: its raw dict for the rewrite, its module for the check
    hp = checkpoint.hyper_parameters  # a copy: the read is shared within the process
    stability = dict(hp.get("stability") or {})
    stability.update({k: bool(v) if isinstance(v, bool) else float(v) for k, v in given.items()})
    checked = BedStability.from_config(stability)
    module = checkpoint.module("fluidized_bed", "cpu", "setting rollout options")
    perturbation_std(module, checked.rollout_noise, "cpu")
    hp["stability"] = stability
    tmp = field.with_suffix(".tmp")
    torch.save({**checkpoint.raw, "hyper_parameters": hp}, tmp)
    tmp.replace(field)
    return {k: getattr(checked, k) if isinstance(getattr(checked, k), bool) else float(getattr(checked, k))
            for k in ROLLOUT_OPTIONS}


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
    p.add_argument("--test-dataset", default=None,
                   help="fluidized bed: score the test part of this dataset of held-out runs (a name under <data "
                        "dir>/datasets or a folder, e.g. fb_small_heldout) instead of the checkpoint's own test runs")
    p.add_argument("--selection", type=Path, default=None,
                   help="fluidized bed: the JSON of `report fb-select` that chose ckpt= (recorded in the card)")
    p.add_argument("--stability-scan", type=Path, default=None,
                   help="fluidized bed: the JSON of `bench fb_stability` over ckpt= (recorded in the card)")
    p.add_argument("--refresh-field", action="store_true",
                   help="fluidized bed, no ckpt=: rerun the shipped model's field answers (test rows, probe) after "
                        "a change of the rollout code, keeping its files and the stored CFD-DEM answers")
    add_arguments(p, ROLLOUT_OPTIONS, default="as trained; written into field.pt, before the test runs are scored")


def dataset_folder(given: str | None, key: str = "test_dataset") -> Path | None:
    """A dataset named on the command line: a folder, or a name under <data dir>/datasets."""
    if given is None:
        return None
    from neuraldem.data.manifest import MANIFEST_NAME, find_dataset
    from neuraldem.paths import data_dir

    folder = find_dataset(given)
    if (folder / MANIFEST_NAME).is_file():
        return folder
    raise ConfigError(f"{key}={given} is no dataset: neither {given} nor {data_dir() / 'datasets' / given} holds a "
                      f"{MANIFEST_NAME}", "generate it (e.g. neuraldem datagen data=fb_small_heldout) or give its "
                      "folder")


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
    folder = build_fluidized_bed(args.ckpt, args.name, args.out, args.dataset, args.lacey_time,
                                 reuse_test=args.reuse_test, rollout_options=options,
                                 test_dataset=dataset_folder(args.test_dataset), selection=args.selection,
                                 stability_scan=args.stability_scan)
    sizes = ", ".join(f"{f.name} {f.stat().st_size / 1e6:.2f} MB" for f in sorted(folder.iterdir()))
    return f"wrote {folder} ({sizes})"
