"""The fluidized bed's speed-accuracy chart, and the smallest model that is accurate enough.

`neuraldem bench fb_speed_accuracy runs=[DIR,...] [dataset=DIR] [solver_variants=[dt:2,substeps:0.5]]
[solver_velocities=2] [reuse_solver=FILE | skip_solver=true] [steps=100] [repeats=3] [threads=1]
[tolerance=0.10] [out=PATH]` writes results/speed_accuracy/fb_speed_accuracy.json, .png and .md.

x = cost of one simulated second of the bed (CPU seconds, one thread); y = the error of what a practitioner
asks of a bed, one panel each: the time-mean solid fraction per cell, its fluctuations (time std per cell),
both as relative L2, and the Lacey mixing index (mean absolute difference over time). Every point is scored
against the same CFD-DEM trajectories: one per held-out (test) velocity, the one the evaluation rolls out from,
over its 3 stored seconds. Points:

- surrogate: every evaluated fluidized-bed run under runs=; errors from its evaluation (rollouts from each test
  velocity's first snapshot, statistics over the CFD-DEM trajectory's steps), cost measured here
  (`fb_speed.surrogate_timing`: steps= rollout steps, median of repeats=, threads= torch threads).
- DPMFoam, another packing: the same velocity started from the dataset's other random packings. Two equally
  valid CFD-DEM runs differ by this much: the floor under any error measured on 3 s of a chaotic bed. Cost:
  what the manifest recorded for those runs.
- DPMFoam at cheaper settings (`dt:K` = K x the CFD step, `substeps:F` = F x the collision substeps), run here
  from the reference trajectory's own packing and velocity, scored like the others; cost of the run measured.

The reference (DPMFoam at the dataset's settings, error 0 by definition) is a vertical line at the manifest's
median cost. Right-sizing: per quantity, the smallest model (fewest parameters, then cheapest) whose error is
within tolerance= (10 %) of the best model's; runs of one config (model and options, not the seed: e.g. the
same sweep run with seed=0 and seed=1) are one model with the mean of their errors. Runs whose rollouts
diverged are drawn but neither right-sized nor on a front.
"""

from __future__ import annotations

import json
import math
import shutil
import statistics
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.bench import plots
from neuraldem.bench.pareto import pareto_front
from neuraldem.bench.report import (
    command_line,
    machine_at_start,
    read_results,
    resolve_out,
    write_results,
)
from neuraldem.cli import command_parser, split_kind_factor
from neuraldem.config import checks
from neuraldem.data.manifest import Manifest, SimRecord, require_dataset
from neuraldem.errors import ConfigError, DataError
from neuraldem.eval.run_results import find_results
from neuraldem.paths import data_dir
from neuraldem.scenes.fluidized_bed.analysis.evaluation import FieldSeries, compare, held_out
from neuraldem.scenes.fluidized_bed.bench.speed import surrogate_timing
from neuraldem.scenes.fluidized_bed.dataset.datagen import packing_seed
from neuraldem.scenes.fluidized_bed.dataset.report import metric_settings
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile, write_fb_file
from neuraldem.scenes.fluidized_bed.solver.runner import STATUS_OK, run_fluidized_bed
from neuraldem.scenes.fluidized_bed.solver.scene import BedScene
from neuraldem.scenes.fluidized_bed.surrogate.option_aliases import RESULT_CONSERVE_KEY
from neuraldem.scenes.fluidized_bed.surrogate.rollout import initial_state
from neuraldem.scenes.fluidized_bed.surrogate.rollout_run import load_fb_checkpoint

NAME = "fb_speed_accuracy"
QUANTITIES = {"solid_fraction_mean_rel_l2": "time-mean solid fraction [rel. L2]",
              "solid_fraction_std_rel_l2": "solid-fraction fluctuations, time std [rel. L2]",
              "lacey_mae": "Lacey mixing index [mean abs. error]"}
SURROGATE, OTHER_PACKING, CHEAPER = "surrogate", "DPMFoam, another packing", "DPMFoam, cheaper settings"
DEFAULT_VARIANTS = ("dt:2", "substeps:0.5")
VARIANT_KINDS = {"dt": "CFD step x K (DEM substeps scale with it)", "substeps": "collision substeps x F"}


def trajectory_errors(c: dict[str, Any]) -> dict[str, float]:
    """The chart's quantities from one comparison (`scenes.fluidized_bed.evaluation.compare`, or a trajectory of
    an evaluation)."""
    return {"solid_fraction_mean_rel_l2": c["rel_l2"]["solid_fraction_mean"],
            "solid_fraction_std_rel_l2": c["rel_l2"]["solid_fraction_std"], "lacey_mae": c["lacey"]["mae"]}


def mean_errors(rows: list[dict[str, float]]) -> dict[str, float]:
    """Mean of each quantity over the rows that have a finite value (NaN if none)."""
    out = {}
    for key in QUANTITIES:
        finite = [r[key] for r in rows if r.get(key) is not None and math.isfinite(r[key])]
        out[key] = float(np.mean(finite)) if finite else float("nan")
    return out


# ---- the trajectories every point is scored on

@dataclass
class Reference:
    dataset_dir: Path
    manifest: Manifest
    records: list[SimRecord]  # one per test velocity (the evaluation's choice), regular trajectories only

    @property
    def ids(self) -> set[str]:
        return {r.sim_id for r in self.records}

    def path(self, rec: SimRecord) -> Path:
        return self.dataset_dir / str(rec.file)


def reference(dataset_dir: Path, split: str) -> Reference:
    m = require_dataset(dataset_dir, dataset_dir.name)
    if m.kind != "fluidized_bed":
        raise DataError(f"{dataset_dir}/manifest.json: kind={m.kind!r}, not a fluidized-bed dataset: pass the "
                        "dataset the runs were trained on (dataset=)")
    regular = float(m.parameters.get("duration", 0.0))
    records = [r for r in held_out(m, split, "test", None) if float(r.params.get("duration", regular)) <= regular]
    if not records:
        raise DataError(f"{dataset_dir}: no finished test trajectory in split {split!r}: generate more with "
                        f"neuraldem datagen data={m.name}")
    return Reference(dataset_dir, m, records)


def truth_series(ref: Reference, rec: SimRecord) -> FieldSeries:
    with BedFile(ref.path(rec)) as f:
        return FieldSeries.from_dataset_file(f)


# ---- surrogate points

def surrogate_point(result: dict[str, Any], ref: Reference, steps: int, repeats: int,
                    threads: int) -> dict[str, Any]:
    """One evaluated run: its errors on the reference trajectories, its rollout cost measured here."""
    trajectories = [t for t in result["trajectories"] if t["sim_id"] in ref.ids]
    if not trajectories:
        raise DataError(f"{result['path']}: evaluated on {[t['sim_id'] for t in result['trajectories']]}, none of "
                        f"the reference trajectories {sorted(ref.ids)} of {ref.dataset_dir}: evaluate it on this "
                        "dataset (neuraldem evaluate ckpt=...)")
    module = load_fb_checkpoint(Path(result["checkpoint"]))
    first = ref.records[0]
    with BedFile(ref.path(first)) as f:
        state = initial_state(f)
    timing = surrogate_timing(module, float(first.params["inlet_velocity"]), state, steps, repeats, threads).as_dict()
    net = module.hparams["net"]
    # what was trained, without the seed: runs with equal configs are seeds of one model (right_size averages)
    # (checkpoints from before an option existed lack its key: fill in its default, which they were trained with)
    config = {"net": {"particle_branch": True, **{k: v for k, v in net.items() if k != "_target_"}},
              "residual": module.hparams.get("residual", False),
              "training": {k: v for k, v in result["training"].items() if k != "parameters"},
              RESULT_CONSERVE_KEY: result.get(RESULT_CONSERVE_KEY, False)}
    diverged = [t for t in trajectories if t["stability"].get("steps_to_divergence") is not None]
    return {"method": SURROGATE, "label": result.get("run", Path(result["path"]).parent.parent.name),
            "time_to_answer_s": timing["median_cpu_s"], "timing": timing,
            "errors": mean_errors([trajectory_errors(t) for t in trajectories]),
            "n_trajectories": len(trajectories), "checkpoint": result["checkpoint"],
            "config": json.loads(json.dumps(config, default=str)),
            # a rollout that diverged is scored on its few steps before: shown, never right-sized or on a front
            "n_diverged": len(diverged),
            "diverged": [{"sim_id": t["sim_id"], "step": t["stability"]["steps_to_divergence"],
                          "reason": t["stability"].get("divergence", "")} for t in diverged],
            "size": {"parameters": result["training"]["parameters"], "dim": net.get("dim"),
                     "n_supernodes_eval": net.get("n_supernodes_eval") or net.get("n_supernodes")},
            "training": result["training"]}


# ---- solver points

def recorded_cost(records: list[SimRecord]) -> float | None:
    """Median DPMFoam CPU seconds per simulated second the manifest recorded for these runs."""
    costs = [r.cost["solver_cpu_s"] / r.cost["simulated_s"] for r in records
             if r.cost.get("solver_cpu_s") and r.cost.get("simulated_s")]
    return statistics.median(costs) if costs else None


def other_packings(ref: Reference) -> dict[str, Any] | None:
    """CFD-DEM against CFD-DEM: each reference trajectory against the same velocity's other packings."""
    m, settings = ref.manifest, metric_settings(ref.manifest)
    rows, used = [], []
    for rec in ref.records:
        v = float(rec.params["inlet_velocity"])
        others = [r for r in m.usable() if r.sim_id != rec.sim_id and math.isclose(float(r.params["inlet_velocity"]), v)
                  and float(r.params.get("duration", 0.0)) == float(rec.params.get("duration", 0.0))]
        if not others:
            continue
        truth = truth_series(ref, rec)
        for other in others:
            rows.append(trajectory_errors(compare(truth_series(ref, other), truth, settings)))
            used.append(other)
    if not rows:
        return None
    return {"method": OTHER_PACKING, "label": "another packing", "time_to_answer_s": recorded_cost(used),
            "errors": mean_errors(rows), "n_trajectories": len(rows), "sims": [r.sim_id for r in used],
            "cost_source": "dataset manifest (recorded at datagen)"}


@dataclass(frozen=True)
class SolverVariant:
    kind: str  # dt | substeps
    factor: float

    @property
    def label(self) -> str:
        return f"{self.kind}:{self.factor:g}"

    @classmethod
    def parse(cls, text: str) -> SolverVariant:
        kind, factor = split_kind_factor(text)
        if kind not in VARIANT_KINDS or not factor > 0:
            raise ConfigError(f"solver_variants={text!r} is invalid: write KIND:FACTOR with KIND one of "
                              f"{sorted(VARIANT_KINDS)} and FACTOR > 0 (e.g. dt:2 or substeps:0.5)")
        return cls(kind, factor)

    def apply(self, scene: BedScene) -> BedScene:
        if self.kind == "dt":
            dt = scene.dt * self.factor
            ratio = scene.snapshot_interval / dt
            if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
                raise ConfigError(f"solver_variants={self.label}: a CFD step of {dt:g} s does not divide the "
                                  f"snapshot interval {scene.snapshot_interval:g} s (pick a factor that does)")
            return replace(scene, dt=dt)
        return replace(scene, collision_resolution_steps=max(1, round(scene.collision_resolution_steps * self.factor)))


def solver_variant_point(variant: SolverVariant, ref: Reference, n_velocities: int, workdir: Path,
                         keep: bool = False) -> dict[str, Any]:
    """DPMFoam at the variant's settings for the first `n_velocities` reference trajectories (same velocity,
    same packing seed, same stored duration), scored against them; failed runs are listed, not scored."""
    m, settings = ref.manifest, metric_settings(ref.manifest)
    base = BedScene.from_config(m.scene["fluidized_bed"], f"{ref.dataset_dir}/manifest.json scene")
    scene = variant.apply(base)
    fields = m.scene.get("fields", {})
    rows, costs, failures = [], [], []
    for rec in ref.records[:n_velocities]:
        folder = Path(workdir) / variant.label.replace(":", "_") / rec.sim_id
        if folder.exists():
            shutil.rmtree(folder)  # each run is timed from scratch
        v, duration = float(rec.params["inlet_velocity"]), float(rec.params["duration"])
        result = run_fluidized_bed(scene, v, duration, folder,
                                   packing_seed(int(m.parameters.get("seed", 0)), rec.index))
        if result.status != STATUS_OK or result.trajectory is None:
            failures.append({"sim_id": rec.sim_id, "reason": result.reason})
            continue
        costs.append(result.cost["solver_cpu_s"] / result.cost["simulated_s"])
        path = folder / "trajectory.h5"
        write_fb_file(path, rec.sim_id, result.trajectory, dict(rec.params), m.solver.get("version", ""),
                      fields.get("kernel_sigma", 0.002), fields.get("mixing_sigma", 0.001),
                      fields.get("prior_solid_fraction", 1e-3))
        with BedFile(path) as f:
            pred = FieldSeries.from_dataset_file(f)
        rows.append({"sim_id": rec.sim_id, **trajectory_errors(compare(pred, truth_series(ref, rec), settings))})
        if not keep:
            shutil.rmtree(folder, ignore_errors=True)
    return {"method": CHEAPER, "label": variant.label, "variant": VARIANT_KINDS[variant.kind].replace(
                "K", f"{variant.factor:g}").replace("F", f"{variant.factor:g}"),
            "settings": {"dt": scene.dt, "collision_resolution_steps": scene.collision_resolution_steps},
            "time_to_answer_s": statistics.median(costs) if costs else float("nan"),
            "errors": mean_errors(rows), "per_trajectory": rows, "n_trajectories": len(rows),
            "n_failed": len(failures), "failures": failures, "n_sims": len(rows) + len(failures)}


# ---- the chart and right-sizing

def chart(points: list[dict[str, Any]]) -> dict[str, list[int]]:
    """Pareto front per quantity over all points (cost, error)."""
    def coord(p: dict[str, Any], key: str) -> tuple[float, float]:
        t, e = p.get("time_to_answer_s"), p["errors"].get(key)
        ok = all(isinstance(x, (int, float)) and math.isfinite(x) for x in (t, e)) and not p.get("n_diverged")
        return (float(t), float(e)) if ok else (math.nan, math.nan)

    return {key: pareto_front([coord(p, key) for p in points]) for key in QUANTITIES}


def config_groups(points: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    """Surrogate points grouped by what was trained (`config`: model, options; not the seed), in first-seen
    order; a point without a config is its own group. Runs that diverged are left out (see surrogate_point)."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for i, p in enumerate(points):
        if p["method"] == SURROGATE and not p.get("n_diverged"):
            key = json.dumps(p["config"], sort_keys=True) if p.get("config") else f"#{i}"
            groups.setdefault(key, []).append(p)
    return list(groups.values())


def family_of(point: dict[str, Any]) -> dict[str, Any]:
    """The options of a run that are not its size (which branches, what it predicts, how it was trained):
    sizes are compared only at equal options."""
    c = point.get("config")
    if not c:
        return {}
    return {"particle_branch": bool(c["net"].get("particle_branch", True)), "residual": bool(c.get("residual")),
            **c.get("training", {}), RESULT_CONSERVE_KEY: bool(c.get(RESULT_CONSERVE_KEY))}


def family_label(f: dict[str, Any]) -> str:
    if not f:
        return "all runs"
    st = f.get("trained_stability")
    if st:  # the stability options of unrolled training (model.stability), when the run records them
        unroll = st.get("unroll", [1.0])
        parts = ["one-step" if len(unroll) == 1 else "unroll " + "/".join(f"{p:g}" for p in unroll),
                 f"input noise {st.get('input_noise') or f.get('input_noise', 0)}",
                 "flux" if f.get("solids_flux") else "no flux", f"mixing {st.get('mixing', 'absolute')}"]
        parts += ["volume projected in training"] if st.get("conserve_volume") else []
        parts += [f"stochastic (CRPS x{st['ensemble']})"] if st.get("ensemble", 1) > 1 else []
    else:
        parts = [f"input noise {f.get('input_noise', 0):g}", f"push-forward k = {f.get('push_forward_steps', 1)}"]
    parts += [name for key, name, on in (("particle_branch", "grid only", False), ("residual", "residual", True),
                                          (RESULT_CONSERVE_KEY, "solid volume projected", True))
              if f.get(key, not on) == on]
    return ", ".join(parts)


def _models(groups: list[list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """One entry per config: its runs' mean error per quantity, their range, size and median cost."""
    out = []
    for runs in groups:
        errors = {k: [p["errors"][k] for p in runs if math.isfinite(p["errors"].get(k, math.nan))] for k in QUANTITIES}
        out.append({"label": runs[0]["label"] + (f" ({len(runs)} runs)" if len(runs) > 1 else ""),
                    "runs": [p["label"] for p in runs], "parameters": runs[0]["size"]["parameters"],
                    "time": statistics.median(p["time_to_answer_s"] for p in runs),
                    "error": {k: float(np.mean(v)) for k, v in errors.items() if v},
                    "spread": {k: [min(v), max(v)] for k, v in errors.items() if v}})
    return out


def right_size(points: list[dict[str, Any]], tolerance: float) -> list[dict[str, Any]]:
    """Sizes compared at equal options (`family_of`): per family and quantity, the best model and the smallest
    (fewest parameters, then cheapest) within (1 + tolerance) x its error, and the smallest within that on
    every quantity at once ("all"). A model's error is the mean over its runs (seeds of one config), so one
    lucky seed does not decide the size."""
    checks.number("tolerance", tolerance, lo=0.0)
    families: dict[str, tuple[dict[str, Any], list[list[dict[str, Any]]]]] = {}
    for runs in config_groups(points):
        family = family_of(runs[0])
        families.setdefault(json.dumps(family, sort_keys=True), (family, []))[1].append(runs)
    out = []
    for family, groups in families.values():
        models = _models(groups)
        picks, limits = {}, {}
        for q in QUANTITIES:
            scored = [m for m in models if q in m["error"]]
            if not scored:
                continue
            best = min(scored, key=lambda m: m["error"][q])
            limits[q] = (1 + tolerance) * best["error"][q]
            ok = [m for m in scored if m["error"][q] <= limits[q]]
            pick = min(ok, key=lambda m: (m["parameters"], m["time"]))
            picks[q] = {"best": best["label"], "best_error": best["error"][q], "limit": limits[q],
                        "pick": pick["label"], "pick_error": pick["error"][q], "pick_runs": pick["runs"],
                        "pick_spread": pick["spread"][q], "pick_parameters": pick["parameters"],
                        "pick_time_to_answer_s": pick["time"], "within": sorted(m["label"] for m in ok)}
        every = [m for m in models
                 if limits and all(q in m["error"] and m["error"][q] <= lim for q, lim in limits.items())]
        all_pick = min(every, key=lambda m: (m["parameters"], m["time"])) if every else None
        out.append({"family": family, "label": family_label(family),
                    "models": [{k: m[k] for k in ("label", "runs", "parameters", "time", "error")} for m in models],
                    "quantities": picks,
                    "all": None if all_pick is None else {"pick": all_pick["label"],
                                                          "parameters": all_pick["parameters"],
                                                          "time_to_answer_s": all_pick["time"],
                                                          "errors": all_pick["error"]}})
    return out


def _num(v: Any, fmt: str) -> str:
    return format(v, fmt) if isinstance(v, (int, float)) and math.isfinite(v) else "n/a"


def render_markdown(results: dict[str, Any]) -> str:
    ref = results["reference"]
    front = {i for idx in results["pareto_front"].values() for i in idx}
    lines = [(f"Scored on {len(results['reference_sims'])} CFD-DEM test trajectories "
              f"({', '.join(results['reference_sims'])}) of {results['dataset']}; cost = CPU seconds per simulated "
              f"second (surrogate: {results['threads']} thread(s), median of {results['repeats']} rollouts of "
              f"{results['steps']} steps). DPMFoam reference: "
              f"{_num(ref['time_to_answer_s'], '.1f')} CPU-s per simulated second ({ref['source']})."), "",
             "| method | point | parameters | CPU-s per simulated s | speed-up vs DPMFoam | "
             + " | ".join(QUANTITIES.values()) + " | on a Pareto front |",
             "|---|---|---|---|---|" + "---|" * len(QUANTITIES) + "---|"]
    for i, p in enumerate(results["points"]):
        t = p.get("time_to_answer_s")
        speedup = ref["time_to_answer_s"] / t if isinstance(t, (int, float)) and t and math.isfinite(t) else None
        params = p.get("size", {}).get("parameters")
        lines.append(f"| {p['method']} | {p['label']} | {f'{params / 1e6:.2f}M' if params else '-'} | "
                     f"{_num(t, '.3g')} | {_num(speedup, ',.0f')}{'x' if speedup else ''} | "
                     + " | ".join(_num(p["errors"].get(k), ".3f") for k in QUANTITIES)
                     + f" | {'yes' if i in front else ''} |")
    failed = [p for p in results["points"] if p.get("n_failed")]
    for p in failed:
        lines.append(f"\n{p['label']}: {p['n_failed']} of {p['n_sims']} DPMFoam runs failed "
                     f"({p['failures'][0]['reason'][:120]}).")
    for p in (p for p in results["points"] if p.get("n_diverged")):
        steps = ", ".join(str(d["step"]) for d in p["diverged"])
        lines.append(f"\n{p['label']}: {p['n_diverged']} of {p['n_trajectories']} rollouts diverged "
                     f"(at steps {steps}); its errors cover the steps before, so it is on no front and not "
                     "right-sized.")
    for fam in results["right_sizing"]:
        if len(fam["models"]) < 2:
            continue  # one size only: nothing to right-size
        lines += ["", (f"Right-sizing at {fam['label']} (smallest model within {100 * results['tolerance']:.0f} % of "
                       "the best; a model's error is the mean over its runs, seeds of one config, their range in "
                       "brackets):"), "",
                  "| quantity | best | best error | smallest within | its error | its parameters "
                  "| its CPU-s per simulated s |",
                  "|---|---|---|---|---|---|---|"]
        for key, r in fam["quantities"].items():
            lo, hi = r["pick_spread"]
            spread = f" ({lo:.3f} - {hi:.3f})" if hi > lo else ""
            lines.append(f"| {QUANTITIES[key]} | {r['best']} | {r['best_error']:.3f} | {r['pick']} | "
                         f"{r['pick_error']:.3f}{spread} | {r['pick_parameters'] / 1e6:.2f}M | "
                         f"{r['pick_time_to_answer_s']:.3g} |")
        a = fam["all"]
        lines.append("| all three at once | | | " + (f"{a['pick']} | | {a['parameters'] / 1e6:.2f}M | "
                                                     f"{a['time_to_answer_s']:.3g} |" if a else "none | | | |"))
    m = results.get("machine", {})
    lines += ["", f"Machine: {m.get('cpu_model', '')} ({m.get('cpu_count', '')} cores).", ""]
    return "\n".join(lines)


def write_outputs(results: dict[str, Any], out: Path, command: str, machine: dict[str, Any]) -> Path:
    path = write_results(NAME, results, command=command, path=out, machine=machine)
    plots.speed_accuracy_figure(results, path.with_suffix(".png"))
    path.with_suffix(".md").write_text(render_markdown(results))
    return path


def main(argv: list[str]) -> int:
    p = command_parser(f"neuraldem.bench {NAME}", __doc__, summary=True)
    p.add_argument("--runs", type=Path, nargs="+", required=True, help="folders holding evaluated fb runs")
    p.add_argument("--dataset", type=Path, default=None, help="dataset dir (default: the runs' own)")
    p.add_argument("--solver-variants", nargs="*", default=list(DEFAULT_VARIANTS), help="KIND:FACTOR, e.g. dt:2")
    p.add_argument("--solver-velocities", type=int, default=2, help="test velocities each variant runs")
    p.add_argument("--reuse-solver", type=Path, default=None, help="take the cheaper-DPMFoam points from this "
                   "earlier fb_speed_accuracy.json instead of running DPMFoam")
    p.add_argument("--skip-solver", action="store_true", help="no cheaper-DPMFoam points")
    p.add_argument("--steps", type=int, default=100, help="rollout steps per timed repeat")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--tolerance", type=float, default=0.10)
    p.add_argument("--workdir", type=Path, default=None, help="where the DPMFoam variant runs go (removed after)")
    p.add_argument("--out", type=Path, default=None)
    a = p.parse_args(argv)
    for name in ("steps", "repeats", "threads", "solver_velocities"):
        checks.positive_int(f"--{name.replace('_', '-')}", getattr(a, name))
    checks.number("tolerance", a.tolerance, lo=0.0)
    variants = [SolverVariant.parse(v) for v in a.solver_variants]
    if a.reuse_solver is not None and a.skip_solver:
        raise ConfigError("reuse_solver= and skip_solver= exclude each other: give one")
    results_in = [r for r in find_results(a.runs) if r.get("kind", "fluidized_bed") == "fluidized_bed"
                  and "trajectories" in r and "rollout_steps" in r]
    if not results_in:
        raise DataError(f"no evaluated fluidized-bed run under {[str(r) for r in a.runs]}: train with experiment=fb "
                        "(evaluate=true) or run neuraldem evaluate ckpt=...")
    datasets = sorted({r["dataset"] for r in results_in})
    if a.dataset is None and len(datasets) > 1:
        raise ConfigError(f"the runs were evaluated on several datasets {datasets}: pick one with dataset=")
    dataset_dir = Path(a.dataset or datasets[0])
    splits = sorted({r["split"] for r in results_in})
    ref = reference(dataset_dir, splits[0])
    reused = read_results(a.reuse_solver, NAME) if a.reuse_solver else None
    machine = machine_at_start()
    points = [surrogate_point(r, ref, a.steps, a.repeats, a.threads) for r in results_in]
    packing = other_packings(ref)
    if packing:
        points.append(packing)
    if reused is not None:
        points += [q for q in reused["results"]["points"] if q["method"] == CHEAPER]
    elif not a.skip_solver:
        workdir = a.workdir or data_dir() / "bench" / NAME
        points += [solver_variant_point(v, ref, a.solver_velocities, workdir) for v in variants]
    ref_cost = recorded_cost([r for r in ref.manifest.usable()
                              if float(r.params.get("duration", 0)) == float(ref.records[0].params["duration"])])
    results = {"dataset": str(dataset_dir), "reference_sims": [r.sim_id for r in ref.records],
               "quantities": QUANTITIES, "points": points, "pareto_front": chart(points),
               "reference": {"time_to_answer_s": ref_cost, "label": "DPMFoam reference (error 0)",
                             "source": "median of the dataset manifest's recorded costs"},
               "xlabel": "cost of one simulated second [CPU s]", "failed_label": "Failed DPMFoam runs: ",
               "right_sizing": right_size(points, a.tolerance),
               "tolerance": a.tolerance, "steps": a.steps, "repeats": a.repeats, "threads": a.threads,
               "machine": machine}
    path = write_outputs(results, resolve_out(a.out, NAME), command_line(NAME, argv), machine)
    print(path.with_suffix(".md").read_text())
    return 0
