"""`neuraldem report fb-select run_dir=RUN_DIR`: choose a bed model's checkpoint on long
validation rollouts, with the rollout options it will be used with.

Why: the rollout validation while training (`callbacks.rollout_validation`: 300 steps = 3 s from one trajectory per
velocity, plain rollouts) keeps one checkpoint, but the model is judged on 3000-step (30-s) rollouts with rollout
noise, and a bed that erupts after 10 s (one seed at 2.05 m/s, results/fluidized_bed/options/
flux_correction_test.md) scores well for 3 s. experiment=fb keeps
every validated checkpoint in RUN_DIR/checkpoints/all/ (2.5 MB each for fb_tiny; elsewhere train with
`callbacks.checkpoint.save_top_k=-1`); this then scores each one from `from_step=` on as `neuraldem evaluate
part=val` does (3000-step rollouts from every validation velocity; the evaluation is called as a function) under
the rollout options, given as on every command (e.g. `rollout.rollout_noise=3 rollout.advection_correction=1
rollout.mirror_alternate=true`; those left out: as trained), ranks them by the pooled score -- rel. L2 of the
per-cell time mean + rel. L2 of the std field + Lacey MAE, each against every CFD-DEM run at the velocity, the sum
the tables report (`scenes.fluidized_bed.table`) -- averaged over `seeds=` (rollout seeds: the noise draws and
particle samples), and copies the winner to RUN_DIR/checkpoints/selected.ckpt (or `copy_to=`).

Each evaluation lands in RUN_DIR/selection/OPTIONS/stepNNNNNN_seedS/evaluation/ (OPTIONS names the rollout options
given, `RolloutOptions.tag()`, e.g. rollout_noise-3+advection_correction-1, or as_trained; metrics.json, report,
plots; `neuraldem report fb-table RUN_DIR/selection/OPTIONS` puts them side by side); a finished one is not
repeated, so a killed selection resumes. The ranking is RUN_DIR/selection/OPTIONS/selection.md (+ .json).
Validation runs only: the test part stays untouched until the choice is made.

`long_val=DATASET_DIR` adds a dataset of long validation trajectories of the same scene (e.g. data=fb_small_longval:
30 s of CFD-DEM at a validation velocity, `data.parameters.long.part: val`): each checkpoint is also rolled out
against it (`evaluate dataset_dir=... part=val`, into .../stepNNNNNN_seedS/<dataset name>/evaluation/) and the ranking
is the mean over every validation velocity of both (each velocity weighs the same). Why: a bed whose statistics
drift after a few seconds (one seed at 2.05 m/s, 3 mm too high from 3 s on, results/fluidized_bed/options/
checkpoint_selection_test.md) matches 3 s of CFD-DEM but not 30. The ranking is then selection_<dataset name>.md
(+ .json), per-source sums beside it.
"""

from __future__ import annotations

import json
import re
import shutil
import sys
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.data.manifest import find_dataset, require_dataset
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import ConfigError, DataError
from neuraldem.paths import data_dir
from neuraldem.scenes.fluidized_bed.analysis.evaluation import POOLED_SCORE_KEYS as SCORE_KEYS
from neuraldem.scenes.fluidized_bed.analysis.evaluation import evaluate_checkpoint, pooled_sum
from neuraldem.scenes.fluidized_bed.surrogate.options import OPTION_NAMES, RolloutOptions, add_arguments

STEP_CKPT = re.compile(r"^step(\d+)\.ckpt$")
SELECTED = "selected.ckpt"
VAL_SOURCE = "val"  # the run's own validation part, beside the long_val= datasets

# (checkpoint, output folder, rollout seed, dataset folder (None: the checkpoint's), rollout options) -> the
# evaluation's metrics.json
Evaluator = Callable[[Path, Path, int, "Path | None", RolloutOptions], Path]


def step_checkpoints(run_dir: Path, from_step: int) -> dict[int, Path]:
    """The run's `stepNNNNNN.ckpt` files from `from_step` on, by training step: those of checkpoints/all/ (every
    validated one, `callbacks.every_checkpoint` of experiment=fb) and of checkpoints/ (the kept ones; all of them
    with `callbacks.checkpoint.save_top_k=-1`)."""
    folder = run_dir / "checkpoints"
    if not folder.is_dir():
        raise DataError(f"{run_dir}: no checkpoints/ folder; give the folder of a training run "
                        "(hydra.run.dir of neuraldem.train)")
    found = {}
    for where in (folder, folder / "all"):  # the same step in both is the same state
        if where.is_dir():
            found |= {int(m.group(1)): p for p in where.iterdir() if (m := STEP_CKPT.match(p.name))}
    chosen = {s: p for s, p in sorted(found.items()) if s >= from_step}
    if len(chosen) < 2:
        raise DataError(f"{folder}: {len(chosen)} step checkpoint(s) from step {from_step} on "
                        f"({sorted(found) or 'none'}), nothing to choose between: train with experiment=fb "
                        "(keeps every validated checkpoint in checkpoints/all/) or callbacks.checkpoint.save_top_k=-1, "
                        "or lower from_step=")
    return chosen


def long_val_datasets(paths: Sequence[Path]) -> dict[str, Path]:
    """long_val= datasets by name, each with long validation trajectories (refused in one line otherwise)."""
    out: dict[str, Path] = {}
    for given in paths:
        path = find_dataset(str(given))  # a folder, or a name under <data dir>/datasets
        m = require_dataset(path, Path(given).name)
        if not m.splits.get("long", {}).get("val"):
            raise ConfigError(f"long_val={given}: dataset {m.name!r} lists no long validation trajectory; give one "
                              "made with data.parameters.long.part=val (e.g. data=fb_small_longval)")
        if m.name in out or m.name == VAL_SOURCE:
            raise ConfigError(f"long_val={given}: a second dataset named {m.name!r}; give each once")
        out[m.name] = Path(path).resolve()
    return out


def run_evaluate(ckpt: Path, out: Path, seed: int, dataset_dir: Path | None, options: RolloutOptions) -> Path:
    """What `neuraldem evaluate ckpt=CKPT part=val vtk=false fluidized_bed.seed=SEED [dataset_dir=DIR]
    <options> hydra.run.dir=OUT` computes and writes (metrics.json, report.md, figures, rollouts), called as a
    function: the same rollouts, the same files."""
    evaluate_checkpoint(ckpt, out_dir=out, datasets_dir=data_dir() / "datasets", dataset_dir=dataset_dir,
                        part="val", seed=seed, vtk=False, options=options)
    return out / "metrics.json"


def pooled_score(metrics: dict, where: Path) -> dict[str, float]:
    """One evaluation's pooled terms, their sum (inf when a rollout diverged: it never wins) and its number of
    velocities (`n`, the weight when evaluations are combined)."""
    a = metrics.get("aggregate", {})
    missing = [k for k in SCORE_KEYS if a.get(k) is None]
    if missing:
        raise DataError(f"{where}: aggregate lacks {missing}; re-run it with the current neuraldem.evaluate "
                        "(delete the folder)")
    terms = {k: float(a[k]) for k in SCORE_KEYS}
    n = int(a.get("n_trajectories", 1))
    stable = a.get("stable_at_10x", n) == n
    terms["sum"] = pooled_sum(list(terms.values())) if stable else float("inf")
    terms["n"] = n
    return terms


def combined_score(parts: Sequence[dict[str, float]]) -> dict[str, float]:
    """Several evaluations of one checkpoint as one: each term the mean over all their velocities."""
    n = sum(p["n"] for p in parts)
    out = {k: sum(p[k] * p["n"] for p in parts) / n for k in SCORE_KEYS}
    stable = all(np.isfinite(p["sum"]) for p in parts)
    out["sum"] = pooled_sum([out[k] for k in SCORE_KEYS]) if stable else float("inf")
    out["n"] = n
    return out


def select(run_dir: Path, from_step: int = 0, options: RolloutOptions | None = None, seeds: Sequence[int] = (0,),
           evaluator: Evaluator = run_evaluate, long_val: Sequence[Path] = (), copy_to: Path | None = None) -> dict:
    """Score every kept checkpoint from `from_step` on under the rollout `options` (resumable), write the
    ranking, copy the winner."""
    options = options or RolloutOptions()
    if not seeds or any(s < 0 for s in seeds):
        raise ConfigError(f"seeds={list(seeds)}: give one or more rollout seeds >= 0 (e.g. seeds=[0,1])")
    longs = long_val_datasets(long_val)
    ckpts = step_checkpoints(run_dir, from_step)
    sel = run_dir / "selection" / options.tag()
    rows = []
    for step, ckpt in ckpts.items():
        per_seed = []
        for seed in seeds:
            base = sel / f"step{step:06d}_seed{seed}"
            sources = {VAL_SOURCE: (base / "evaluation", None)}  # where the tables look (fb-table)
            sources |= {name: (base / name / "evaluation", path) for name, path in longs.items()}
            parts = {}
            for name, (out, dataset_dir) in sources.items():
                metrics = out / "metrics.json"
                if not metrics.is_file():
                    metrics = evaluator(ckpt, out, seed, dataset_dir, options)
                parts[name] = pooled_score(json.loads(metrics.read_text()), metrics)
            per_seed.append({**combined_score(list(parts.values())),
                             "by_source": {k: v["sum"] for k, v in parts.items()}})
        mean = {k: float(np.mean([s[k] for s in per_seed])) for k in (*SCORE_KEYS, "sum")}
        by_source = {k: float(np.mean([s["by_source"][k] for s in per_seed])) for k in per_seed[0]["by_source"]}
        rows.append({"step": step, "checkpoint": str(ckpt), **mean, "sum_per_seed": [s["sum"] for s in per_seed],
                     "sum_by_source": by_source, "n_velocities": per_seed[0]["n"]})
    best = min(rows, key=lambda r: (r["sum"], -r["step"]))  # a tie goes to the longer-trained net
    target = Path(copy_to) if copy_to else run_dir / "checkpoints" / SELECTED
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_suffix(".tmp")
    shutil.copyfile(best["checkpoint"], tmp)
    tmp.replace(target)
    doc = {"run_dir": str(run_dir), "from_step": from_step, **options.as_dict(), "seeds": list(seeds),
           "long_val": {k: str(v) for k, v in longs.items()}, "rows": rows,
           "selected": {"step": best["step"], "checkpoint": best["checkpoint"], "copied_to": str(target)},
           "date_utc": datetime.now(UTC).isoformat(timespec="seconds")}
    stem = "selection" + "".join(f"_{k}" for k in longs)
    atomic_write_json(sel / f"{stem}.json", doc)
    (sel / f"{stem}.md").write_text(render(doc))
    return doc


def render(doc: dict) -> str:
    options = RolloutOptions.from_config({k: doc.get(k) for k in OPTION_NAMES})
    opts = (f"rollout options {' '.join(options.overrides()) or 'as trained'}"
            f"{' (the others as trained)' if options.given() else ''}, rollout seeds {doc['seeds']}")
    longs = list(doc.get("long_val") or {})
    where = "Validation part" + "".join(f" + the long validation trajectories of {k}" for k in longs)
    lines = [f"# Checkpoint selection: {doc['run_dir']}", "",
             f"{where}, rollouts of 10x the training horizon (3000 steps on fb_small), {opts}; "
             "pooled against every CFD-DEM run at each velocity, "
             "means over the velocities (and seeds). Selected: step "
             f"{doc['selected']['step']} -> {doc['selected']['copied_to']}.", "",
             "| step | rel. L2 mean solid fraction | rel. L2 std solid fraction | Lacey MAE | sum | sum per seed |"
             + "".join(f" sum {k} |" for k in [VAL_SOURCE, *longs] if longs),
             "|---|---|---|---|---|---|" + "---|" * (len(longs) + 1 if longs else 0)]
    for r in doc["rows"]:
        mark = " **selected**" if r["step"] == doc["selected"]["step"] else ""
        by_source = "".join(f" {r['sum_by_source'][k]:.3f} |" for k in [VAL_SOURCE, *longs] if longs)
        lines.append(f"| {r['step']}{mark} | {r[SCORE_KEYS[0]]:.3f} | {r[SCORE_KEYS[1]]:.3f} | {r[SCORE_KEYS[2]]:.3f} "
                     f"| {r['sum']:.3f} | {' / '.join(f'{s:.3f}' for s in r['sum_per_seed'])} |{by_source}")
    return "\n".join(lines) + "\n"


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = doc_parser("neuraldem.scenes.fluidized_bed.surrogate.selection", __doc__)
    p.add_argument("run_dir", type=Path, help="a fluidized-bed training run (hydra.run.dir of neuraldem.train)")
    p.add_argument("--from-step", type=int, default=0, help="skip checkpoints before this training step")
    add_arguments(p)
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="rollout seeds to average over")
    p.add_argument("--long-val", type=Path, nargs="+", default=[],
                   help="datasets (folders or names under <data dir>/datasets, e.g. fb_small_longval) of long "
                        "validation trajectories of the same scene (data.parameters.long.part=val), pooled into the "
                        "ranking")
    p.add_argument("--copy-to", type=Path, default=None,
                   help=f"where the winner is copied (default RUN_DIR/checkpoints/{SELECTED}; one file per set of "
                        "options when several selections of one run are kept, as scripts/fb_ablation.sh does)")
    a = p.parse_args(argv)
    doc = select(a.run_dir, a.from_step, RolloutOptions.from_args(a), a.seeds, long_val=a.long_val,
                 copy_to=a.copy_to)
    print(render(doc), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
