"""The solver's own noise floor: LIGGGHTS rerun for stored parameter sets with other packing seeds.

A hopper run depends on the random packing; a surrogate cannot be expected to agree with the stored run better
than another run of the same parameters does. For N parameter sets of a dataset (spread over the parameter
space, chosen reproducibly from seed=) LIGGGHTS is rerun K times, each with packing seeds no stored run uses,
stored like a dataset run (`<workdir>/files/`) and scored from that file with the functions that scored the
dataset (`scenes.hopper.datagen.stored_metrics` on the scene's max_time grid, the manifest's metric settings; new
settings rescore the stored reruns without running them again). Reported:

  rerun vs stored  `scenes.hopper.scoring.score_answers` of the reruns against the stored runs: "LIGGGHTS with
                   another seed" as a method, in the units of the surrogate's table (directly comparable rows)
  seed spread      per quantity, the mean over sets of the standard deviation across the K + 1 runs of a set
                   (stored + reruns); drainage times as % of their mean, outflow relative to the set's mean,
                   residuals in percentage points
  cost             median solver CPU (and wall) seconds per rerun: the method's time to answer

`neuraldem bench seed_floor dataset=DIR [n_sets=10] [seeds=3] [workers=1] [seed=0]
[out=results/hopper/accuracy/seed_floor.json] [workdir=DIR]` writes the JSON and a markdown table beside it. Every
finished rerun is written at once to `<workdir>/reruns.json`; a restarted command reruns only what is missing.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from neuraldem.bench.choices import default_workdir
from neuraldem.bench.report import command_line, resolve_out, warn_if_busy, write_results
from neuraldem.cli import command_parser
from neuraldem.config import checks
from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import ConfigError, DataError, NeuraldemError, SolverInterrupted
from neuraldem.machine import machine_info
from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings
from neuraldem.scenes.hopper.analysis.scoring import HOPPER_ERRORS, score_answers
from neuraldem.scenes.hopper.bench.solver import dataset_scene, run_scene
from neuraldem.scenes.hopper.dataset.datagen import stored_metrics
from neuraldem.scenes.hopper.dataset.store import write_hopper_file
from neuraldem.scenes.hopper.solver import STATUS_CLOGGED, STATUS_FAILED, STATUS_OK, HopperScene
from neuraldem.sim.liggghts import find_liggghts
from neuraldem.sim.seeds import prime_seeds

NAME = "seed_floor"
# rerun k of the run with index i uses the seeds of index SEED_OFFSET * k + i: no stored run (index < offset)
# shares them, and the primes stay below LIGGGHTS's 32-bit seed limit for up to MAX_SEEDS reruns
SEED_OFFSET = 10_000
SEEDS_PER_RUN = 3  # prime_seeds(index, 3) in scenes.hopper.solver.run_hopper
MAX_SEED = 2**31 - 1
CACHE_NAME = "reruns.json"
CACHE_VERSION = 1
METRIC_KEYS = ("drainage_t95", "drainage_time", "residual_fraction", "residual_fraction_particles",
               "outflow_rate", "mass_flow_index", "mass_flow")
# quantity -> (how its spread is expressed, the score_answers error it compares with, label)
SPREAD = {
    "drainage_t95": ("pct_of_mean", "drainage_t95_pct_of_mean", "drainage time t95 [% of mean]"),
    "drainage_time": ("pct_of_mean", "drainage_mae_pct_of_mean", "drainage time (1 % rule) [% of mean]"),
    "residual_fraction": ("pp", "residual_mae_pp", "residual [percentage points]"),
    "residual_fraction_particles": ("pp", None, "residual, particle count [percentage points]"),
    "outflow_rate": ("rel_pct", "outflow_rel_err_pct", "outflow rate [% of the set's mean]"),
    "mass_flow_index": ("abs", None, "mass-flow index [index units]"),
}
SELECTION = ("farthest-point sampling over the usable runs in parameters scaled to [0, 1] by the dataset's "
             "ranges, the first run drawn at random with seed=")


# ---- which parameter sets

def select_records(m: Manifest, n_sets: int, seed: int, keep: Sequence[str] = ()) -> list[SimRecord]:
    """`n_sets` usable runs spread over the parameter space, the same for the same dataset and seed.

    `keep` (sim ids already rerun, in cache order) are chosen first and the rest placed farthest from them, so
    that a dataset grown by datagen between two calls does not discard finished reruns.
    """
    usable = sorted(m.usable(), key=lambda r: r.index)
    if n_sets > len(usable):
        raise DataError(f"dataset {m.name!r} has {len(usable)} usable run(s), fewer than n_sets={n_sets}: pass "
                        f"n_sets={len(usable)} or less, or generate more runs with `neuraldem datagen "
                        f"data={m.name} n_sims=...`")
    names = sorted(usable[0].params)
    x = np.array([[r.params[k] for k in names] for r in usable], dtype=np.float64)
    ranges = (m.parameters or {}).get("ranges") or {}
    lo, hi = np.array([ranges.get(k, [x[:, j].min(), x[:, j].max()]) for j, k in enumerate(names)],
                      dtype=np.float64).T
    position = {r.sim_id: i for i, r in enumerate(usable)}
    start = list(dict.fromkeys(position[s] for s in keep if s in position))[:n_sets]
    scaled = (x - lo) / np.where(hi > lo, hi - lo, 1.0)
    return [usable[i] for i in farthest_points(scaled, n_sets, seed, start)]


def farthest_points(x: np.ndarray, n: int, seed: int, start: Sequence[int] = ()) -> list[int]:
    """Greedy maximin choice of `n` rows of `x`: each next row is the farthest from those already chosen
    (`start`, else one row drawn with `seed`)."""
    chosen = list(start) or [int(np.random.default_rng(seed).integers(len(x)))]
    dist = np.min([np.linalg.norm(x - x[c], axis=1) for c in chosen], axis=0)
    while len(chosen) < n:
        dist[chosen] = -np.inf  # never twice, even among duplicate parameter sets
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(x - x[nxt], axis=1))
    return chosen


def rerun_index(index: int, k: int) -> int:
    """The run index whose packing seeds rerun k (1..K) of stored run `index` uses."""
    return SEED_OFFSET * k + index


def check_seed_range(records: Sequence[SimRecord], seeds: int) -> None:
    """Refuse seeds that collide with stored runs or overflow LIGGGHTS's 32-bit seeds, before any run."""
    top = max(r.index for r in records)
    if top >= SEED_OFFSET:
        raise DataError(f"run index {top} >= {SEED_OFFSET}: reruns of this dataset could share packing seeds with "
                        "stored runs; pick parameter sets of lower index (another seed=) or raise SEED_OFFSET in "
                        "neuraldem/scenes/hopper/bench/seed_floor.py")
    if prime_seeds(rerun_index(top, seeds), SEEDS_PER_RUN)[-1] > MAX_SEED:
        most = max(k for k in range(1, seeds + 1)
                   if prime_seeds(rerun_index(top, k), SEEDS_PER_RUN)[-1] <= MAX_SEED)
        raise ConfigError(f"seeds={seeds}: the packing seeds of the last reruns exceed LIGGGHTS's 32-bit seed "
                          f"range: pass seeds={most} or less")


# ---- reruns and their cache

def cache_header(scene: HopperScene, settings: HopperMetricSettings) -> dict[str, Any]:
    """What a cached rerun depends on: reruns of another scene or seed scheme are not reused; reruns scored
    with other metric settings are rescored from their stored trajectories (no solver run)."""
    return json.loads(json.dumps({"version": CACHE_VERSION, "scene": scene.as_dict(),
                                  "metric_settings": settings.as_dict(), "seed_offset": SEED_OFFSET}))


RESCORABLE = ("metric_settings",)  # header keys whose change needs no rerun


def run_key(rec: SimRecord, k: int) -> str:
    return f"{rec.sim_id}/seed{k}"


def load_cache(path: Path, header: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Finished reruns of an earlier call of this command (empty when there is none)."""
    if not path.is_file():
        return {}
    try:
        payload = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise DataError(f"{path} is not valid JSON ({err}): delete it (its reruns are run again)") from None
    differs = [k for k in header if payload.get("header", {}).get(k) != header[k]]
    fatal = [k for k in differs if k not in RESCORABLE]
    if fatal:
        raise DataError(f"{path} holds reruns made with another {', '.join(fatal)}: delete it, or pass another "
                        "workdir= to keep it")
    runs = dict(payload.get("runs", {}))
    if differs:  # new metric settings: rescore what has its trajectory, run again what has not
        settings = HopperMetricSettings.from_config(header["metric_settings"], f"{path} metric_settings")
        for key, row in list(runs.items()):
            file = row.get("file")
            if file and (path.parent / file).is_file() and row.get("metrics") is not None:
                row["metrics"] = score_file(path.parent / file, header, settings)
            else:
                del runs[key]
        save_cache(path, header, runs)
    return runs


def score_file(path: Path, header: dict[str, Any], settings: HopperMetricSettings) -> dict[str, float]:
    """A stored rerun's metrics, computed like the dataset's (`scenes.hopper.datagen.stored_metrics`)."""
    hop = header["scene"]
    return stored_metrics(path, float(hop["material"]["diameter"]), settings, float(hop["max_time"]))


def save_cache(path: Path, header: dict[str, Any], runs: dict[str, dict[str, Any]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, {"header": header, "runs": runs})


def rerun(scene: HopperScene, rec: SimRecord, k: int, settings: HopperMetricSettings, workdir: Path,
          storage: tuple[str, float] = ("LIGGGHTS", 1e-5)) -> dict[str, Any]:
    """One rerun with new packing seeds, stored like a dataset run (`files/`, so new metric settings rescore
    it without running again) and scored from the stored file like the dataset; a failed run is recorded,
    not raised. `storage`: (solver version, position resolution) of the dataset's files."""
    index = rerun_index(rec.index, k)
    row: dict[str, Any] = {"sim_id": rec.sim_id, "index": rec.index, "params": dict(rec.params), "seed": k,
                           "run_index": index, "packing_seeds": prime_seeds(index, SEEDS_PER_RUN),
                           "status": STATUS_FAILED, "reason": "", "metrics": None}
    try:
        result = run_scene(scene, rec.params, workdir / f"{rec.sim_id}_seed{k}", index)
    except SolverInterrupted:
        raise  # killed from outside: stays unfinished, the next call runs it
    except NeuraldemError as err:
        return {**row, "reason": str(err)}
    diag = result.diagnostics
    row.update(status=result.status, reason=result.reason, cpu_s=diag.get("cpu_s"), wall_s=diag.get("wall_s"),
               ended_by=diag.get("ended_by"))
    if result.trajectory is not None and result.status != STATUS_FAILED:
        rel = f"files/{rec.sim_id}_seed{k}.h5"
        (workdir.parent / "files").mkdir(parents=True, exist_ok=True)
        write_hopper_file(workdir.parent / rel, f"{rec.sim_id}_seed{k}", result.trajectory, dict(rec.params),
                          storage[0], storage[1])
        t0 = time.perf_counter()
        row["metrics"] = stored_metrics(workdir.parent / rel, scene.material.diameter, settings, scene.max_time)
        row["metrics_s"] = time.perf_counter() - t0
        row["file"] = rel
    return row


def run_missing(scene: HopperScene, records: list[SimRecord], seeds: int, settings: HopperMetricSettings,
                workdir: Path, workers: int, progress: bool = True,
                storage: tuple[str, float] = ("LIGGGHTS", 1e-5)) -> dict[str, dict[str, Any]]:
    """Every (set, seed) rerun, from the cache where finished; each new one is cached as it finishes."""
    cache_path, header = workdir / CACHE_NAME, cache_header(scene, settings)
    runs = load_cache(cache_path, header)
    todo = [(rec, k) for rec in records for k in range(1, seeds + 1)
            if runs.get(run_key(rec, k), {}).get("params") != dict(rec.params)]
    if todo:
        find_liggghts()
    bar = tqdm(total=len(records) * seeds, initial=len(records) * seeds - len(todo), desc=f"{NAME} reruns",
               unit="run", disable=not progress, dynamic_ncols=True)
    interrupted: SolverInterrupted | None = None
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures: dict[Future[dict[str, Any]], str] = {
            pool.submit(rerun, scene, rec, k, settings, workdir / "runs", storage): run_key(rec, k)
            for rec, k in todo}
        for fut in as_completed(futures):
            if fut.cancelled():  # queued when another run was interrupted: it stays to do
                continue
            try:
                row = fut.result()
            except SolverInterrupted as err:
                interrupted = interrupted or err
                for other in futures:
                    other.cancel()
                continue
            runs[futures[fut]] = row
            save_cache(cache_path, header, runs)
            bar.update(1)
            if row["status"] != STATUS_OK:
                bar.write(f"{futures[fut]}: {row['status']}: {row['reason']}")
    bar.close()
    if interrupted is not None:
        raise interrupted
    return runs


# ---- what the reruns say

def std_per_set(values: Sequence[float]) -> tuple[float, float] | None:
    """(sample standard deviation, mean) of a set's finite values; None with fewer than two."""
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=np.float64)
    return (float(np.std(v, ddof=1)), float(np.mean(v))) if len(v) >= 2 else None


def seed_spread(groups: Sequence[Sequence[dict[str, float]]]) -> dict[str, dict[str, Any]]:
    """Per quantity, the mean over sets of the spread across a set's runs (each group: stored + reruns).

    Drainage times: mean std / mean value x 100 (like score_answers' % of mean); outflow: mean of std / set
    mean x 100 (a relative error per run); residuals: mean std x 100 (percentage points); mass-flow index: mean
    std. Flow regime: the share of sets whose runs all fall in one regime."""
    out: dict[str, dict[str, Any]] = {}
    for key, (unit, error_key, label) in SPREAD.items():
        stats = [s for g in groups if (s := std_per_set([m.get(key, np.nan) for m in g])) is not None]
        out[key] = {"value": spread_value(stats, unit), "unit": unit, "label": label, "comparable_error": error_key,
                    "n_sets": len(stats)}
    regimes = [{m["mass_flow"] for m in g if np.isfinite(m.get("mass_flow", np.nan))} for g in groups]
    regimes = [r for r in regimes if r]
    out["mass_flow"] = {"value": float(np.mean([len(r) == 1 for r in regimes])) if regimes else None,
                        "unit": "share", "label": "flow regime: share of sets with one regime across seeds",
                        "comparable_error": "flow_regime_accuracy", "n_sets": len(regimes)}
    return out


def spread_value(stats: list[tuple[float, float]], unit: str) -> float | None:
    if not stats:
        return None
    std, mean = np.array(stats).T
    if unit == "pct_of_mean":
        return float(100 * std.mean() / mean.mean())
    if unit == "rel_pct":
        return float(100 * np.mean(std / np.abs(mean))) if np.all(mean != 0) else None
    return float(100 * std.mean()) if unit == "pp" else float(std.mean())


def stored_truth(rec: SimRecord, dataset_dir: Path) -> dict[str, float]:
    """The stored run's metrics as in the manifest (scored with its metric settings on the max_time grid)."""
    missing = [k for k in METRIC_KEYS if k not in rec.metrics]
    if missing:
        raise DataError(f"{dataset_dir}/manifest.json: simulation {rec.sim_id} has no metrics {missing}: rescore "
                        "the dataset with this neuraldem (`neuraldem datagen data=...` resumes and "
                        "rescores)")
    return {k: float(rec.metrics[k]) for k in METRIC_KEYS}


def summarize(records: list[SimRecord], runs: dict[str, dict[str, Any]], seeds: int,
              dataset_dir: Path) -> dict[str, Any]:
    """Rerun-vs-stored scores, seed spread, counts and cost of the reruns of `records`."""
    rows = [runs[run_key(rec, k)] for rec in records for k in range(1, seeds + 1)]
    stored = {rec.sim_id: stored_truth(rec, dataset_dir) for rec in records}
    ok = [r for r in rows if r["status"] == STATUS_OK and r["metrics"]]
    answered = [r for r in rows if r["metrics"]]
    groups = [[stored[rec.sim_id]] + [r["metrics"] for r in ok if r["sim_id"] == rec.sim_id] for rec in records]
    score = score_answers([stored[r["sim_id"]] for r in ok], [r["metrics"] for r in ok]) if ok else None
    clogged = [r for r in answered if r["status"] == STATUS_CLOGGED]
    with_clogged = (score_answers([stored[r["sim_id"]] for r in answered], [r["metrics"] for r in answered])
                    if clogged else None)
    cost = {"cpu_s_per_rerun_median": _median([r.get("cpu_s") for r in answered]),
            "wall_s_per_rerun_median": _median([r.get("wall_s") for r in answered]),
            "metrics_s_per_rerun_median": _median([r.get("metrics_s") for r in answered]), "n_runs": len(answered)}
    counts = {s: sum(r["status"] == s for r in rows) for s in (STATUS_OK, STATUS_CLOGGED, STATUS_FAILED)}
    point = {"method": "liggghts", "label": "LIGGGHTS, other packing seed", "variant": "seed",
             "errors": {k: score[k] for k in HOPPER_ERRORS} if score else {},
             "time_to_answer_s": cost["cpu_s_per_rerun_median"], "cpu_s": cost["cpu_s_per_rerun_median"],
             "wall_s": cost["wall_s_per_rerun_median"]}
    return {"rerun_vs_stored": score, "rerun_vs_stored_with_clogged": with_clogged, "seed_spread": seed_spread(groups),
            "cost": cost, "counts": counts, "point": point, "stored": stored, "runs": rows}


def _median(values: list[Any]) -> float | None:
    v = [float(x) for x in values if x is not None]
    return float(np.median(v)) if v else None


# ---- report

def render_markdown(results: dict[str, Any]) -> str:
    score, spread, cost, counts = (results["rerun_vs_stored"] or {}), results["seed_spread"], results["cost"], \
        results["counts"]
    lines = [f"LIGGGHTS seed floor of {results['scene']}: {results['n_sets']} parameter sets x {results['seeds']} new "
             f"packing seeds ({counts['ok']} ok, {counts['clogged']} clogged, {counts['failed']} failed reruns); "
             f"sets: {results['selection']['method']}.",
             f"Median cost per rerun: {_num(cost['cpu_s_per_rerun_median'])} CPU s "
             f"({_num(cost['wall_s_per_rerun_median'])} wall s), serial LIGGGHTS.",
             "",
             "| quantity | seed spread (std across stored + reruns) | rerun vs stored error | error unit |",
             "|---|---|---|---|"]
    for s in spread.values():
        error_key = s["comparable_error"]
        err = _num(score.get(error_key)) if error_key else "-"
        unit = HOPPER_ERRORS.get(error_key, "share of runs in the stored run's regime"
                                 if error_key == "flow_regime_accuracy" else "-")
        lines.append(f"| {s['label']} | {_num(s['value'])} | {err} | {unit} |")
    lines += ["", "| set | alpha | mu_s | mu_r | t95 stored [s] | t95 reruns [s] | residual stored | residual reruns |",
              "|---|---|---|---|---|---|---|---|"]
    for sim_id, truth in results["stored"].items():
        reruns = [r for r in results["runs"] if r["sim_id"] == sim_id]
        p = reruns[0]["params"]
        lines.append(f"| {sim_id} | {p['alpha']:.1f} | {p['mu_s']:.2f} | {p['mu_r']:.2f} | "
                     f"{truth['drainage_t95']:.3f} | {_values(reruns, 'drainage_t95', '.3f')} | "
                     f"{truth['residual_fraction']:.3f} | {_values(reruns, 'residual_fraction', '.3f')} |")
    return "\n".join(lines) + "\n"


def _num(v: float | None) -> str:
    return "n/a" if v is None or not np.isfinite(v) else f"{v:.2f}"


def _values(reruns: list[dict[str, Any]], key: str, fmt: str) -> str:
    return ", ".join(format(r["metrics"][key], fmt) if r["metrics"] else r["status"] for r in reruns)


@dataclass(frozen=True)
class Plan:
    """What the command reruns, checked before any solver starts."""

    dataset: Path
    scene: HopperScene
    manifest: Manifest
    settings: HopperMetricSettings
    records: list[SimRecord]
    seeds: int
    seed: int
    workdir: Path


def plan(dataset: Path, n_sets: int, seeds: int, seed: int, workdir: Path | None) -> Plan:
    scene, m = dataset_scene(dataset)
    settings = HopperMetricSettings.from_config(m.metric_settings or {}, f"{dataset}/manifest.json metric_settings")
    workdir = Path(workdir) if workdir is not None else default_workdir(NAME) / m.name
    cached = load_cache(workdir / CACHE_NAME, cache_header(scene, settings))  # refuses a cache of other runs
    params = {r.sim_id: dict(r.params) for r in m.simulations}
    rerun = [(key.split("/")[0], row) for key, row in cached.items()]  # keys are run_key(): "<sim_id>/seed<k>"
    done = [sim_id for sim_id, row in rerun if row.get("params") == params.get(sim_id)]
    records = select_records(m, n_sets, seed, keep=done)
    check_seed_range(records, seeds)
    for rec in records:
        stored_truth(rec, Path(dataset))
    return Plan(Path(dataset), scene, m, settings, records, seeds, seed, workdir)


def run(p: Plan, workers: int, progress: bool = True) -> dict[str, Any]:
    storage = (str(p.manifest.solver.get("version", "LIGGGHTS")),
               float(p.manifest.scene.get("position_resolution", 1e-5)))
    runs = run_missing(p.scene, p.records, p.seeds, p.settings, p.workdir, workers, progress, storage)
    out = {"scene": p.manifest.name, "dataset": str(p.dataset.resolve()), "n_sets": len(p.records), "seeds": p.seeds,
           "seed_offset": SEED_OFFSET, "horizon_s": p.scene.max_time, "metric_settings": p.settings.as_dict(),
           "selection": {"method": SELECTION, "seed": p.seed, "sim_ids": [r.sim_id for r in p.records]},
           "quantities": HOPPER_ERRORS, "workdir": str(p.workdir), "cache": str(p.workdir / CACHE_NAME)}
    out.update(summarize(p.records, runs, p.seeds, p.dataset))
    return out


def main(argv: list[str]) -> int:
    p = command_parser(f"neuraldem.bench {NAME}", __doc__, summary=True)
    p.add_argument("--dataset", type=Path, required=True, help="hopper dataset dir (its scene and stored runs)")
    p.add_argument("--n-sets", type=int, default=10, help="parameter sets rerun (usable runs of the dataset)")
    p.add_argument("--seeds", type=int, default=3, help="reruns per set, each with new packing seeds")
    p.add_argument("--workers", type=int, default=1, help="LIGGGHTS runs side by side (each serial)")
    p.add_argument("--seed", type=int, default=0, help="seed of the parameter-set choice")
    p.add_argument("--workdir", type=Path, default=None,
                   help=f"solver runs and the rerun cache (default <data dir>/bench/{NAME}/<dataset name>)")
    p.add_argument("--out", type=Path, default=None,
                   help=f"default results/hopper/accuracy/{NAME}.json (+ .md beside it)")
    a = p.parse_args(argv)
    checks.positive_int("n_sets", a.n_sets)
    checks.positive_int("seeds", a.seeds)
    checks.positive_int("workers", a.workers)
    checks.positive_int("seed", a.seed, allow_zero=True)
    out = resolve_out(a.out, NAME)
    todo = plan(a.dataset, a.n_sets, a.seeds, a.seed, a.workdir)  # everything that can fail, before any run
    machine = machine_info()
    warning = warn_if_busy(machine)
    results = run(todo, a.workers)
    results["warning"] = warning
    path = write_results(NAME, results, command=command_line(NAME, argv), path=out, machine=machine)
    text = render_markdown(results)
    path.with_suffix(".md").write_text(text)
    print(text)
    print(f"wrote {path} and {path.with_suffix('.md')}")
    return 0
