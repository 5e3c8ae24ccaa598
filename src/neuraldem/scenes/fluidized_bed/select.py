"""`python -m neuraldem.scenes.fluidized_bed.select RUN_DIR`: choose a bed model's checkpoint on long validation
rollouts, with the rollout options it will be used with.

Why: the rollout validation while training (`callbacks.rollout_validation`: 300 steps = 3 s from one trajectory per
velocity, plain rollouts) keeps one checkpoint, but the model is judged on 3000-step (30-s) rollouts with rollout
noise, and a bed that erupts after 10 s (stop 40: one seed at 2.05 m/s) scores well for 3 s. experiment=fb keeps
every validated checkpoint in RUN_DIR/checkpoints/all/ (2.5 MB each for fb_tiny; elsewhere train with
`callbacks.checkpoint.save_top_k=-1`); this then scores each one from `--from-step` on with `neuraldem.evaluate
part=val` (3000-step rollouts from every validation velocity) under `--rollout-noise` / `--advection-correction` /
`--mirror-alternate`, ranks them by the pooled score -- rel. L2 of the per-cell time mean + rel. L2 of the std
field + Lacey MAE, each against every CFD-DEM run at the velocity, the sum the tables report
(`scenes.fluidized_bed.table`) -- averaged over `--seeds` (rollout seeds: the noise draws and particle samples),
and copies the winner to RUN_DIR/checkpoints/selected.ckpt.

Each evaluation lands in RUN_DIR/selection/OPTIONS/stepNNNNNN_seedS/evaluation/ (OPTIONS names the rollout
options, e.g. noise3_corr1; metrics.json, report, plots; `neuraldem report fb-table RUN_DIR/selection/OPTIONS` puts
them side by side); a finished one is not repeated, so a killed selection resumes. The ranking is
RUN_DIR/selection/OPTIONS/selection.md (+ .json). Validation runs only: the test part stays
untouched until the choice is made.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.config import checks
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes.fluidized_bed.stability import MAX_ROLLOUT_NOISE

STEP_CKPT = re.compile(r"^step(\d+)\.ckpt$")
SCORE_KEYS = ("pooled_solid_fraction_mean_rel_l2", "pooled_solid_fraction_std_rel_l2", "pooled_lacey_mae")
SELECTED = "selected.ckpt"

# (checkpoint, output folder, evaluate overrides) -> the evaluation's metrics.json
Evaluator = Callable[[Path, Path, list[str]], Path]


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
                        "or lower --from-step")
    return chosen


def options_tag(rollout_noise: float | None, advection_correction: float | None,
                mirror_alternate: bool | None) -> str:
    """The folder name of one set of rollout options (e.g. noise3_corr1_alt), so that a selection under other
    options never reuses these evaluations."""
    parts = ([] if rollout_noise is None else [f"noise{rollout_noise:g}"]) + \
        ([] if advection_correction is None else [f"corr{advection_correction:g}"]) + \
        ([] if mirror_alternate is None else ["alt" if mirror_alternate else "noalt"])
    return "_".join(parts) or "as_trained"


def rollout_overrides(rollout_noise: float | None, advection_correction: float | None, seed: int,
                      mirror_alternate: bool | None = None) -> list[str]:
    out = [f"fluidized_bed.seed={seed}"]
    if mirror_alternate is not None:
        out.append(f"fluidized_bed.mirror_alternate={str(mirror_alternate).lower()}")
    if rollout_noise is not None:
        out.append(f"fluidized_bed.rollout_noise={rollout_noise:g}")
    if advection_correction is not None:
        out.append(f"fluidized_bed.advection_correction={advection_correction:g}")
    return out


def run_evaluate(ckpt: Path, out: Path, overrides: list[str]) -> Path:
    """`neuraldem.evaluate` on the validation part, in its own process (as a user would run it)."""
    cmd = [sys.executable, "-m", "neuraldem.evaluate", f"ckpt={ckpt}", "part=val", "vtk=false", *overrides,
           f"hydra.run.dir={out}"]
    done = subprocess.run(cmd, check=False)
    metrics = out / "metrics.json"
    if done.returncode != 0 or not metrics.is_file():
        raise DataError(f"evaluating {ckpt} failed (exit {done.returncode}): see {out / 'evaluate.log'}")
    return metrics


def pooled_score(metrics: dict, where: Path) -> dict[str, float]:
    a = metrics.get("aggregate", {})
    missing = [k for k in SCORE_KEYS if a.get(k) is None]
    if missing:
        raise DataError(f"{where}: aggregate lacks {missing}; re-run it with the current neuraldem.evaluate "
                        "(delete the folder)")
    terms = {k: float(a[k]) for k in SCORE_KEYS}
    stable = a.get("stable_at_10x", a.get("n_trajectories")) == a.get("n_trajectories")
    terms["sum"] = sum(terms.values()) if stable else float("inf")  # a diverged rollout never wins
    return terms


def select(run_dir: Path, from_step: int = 0, rollout_noise: float | None = None,
           advection_correction: float | None = None, seeds: Sequence[int] = (0,),
           evaluator: Evaluator = run_evaluate, mirror_alternate: bool | None = None) -> dict:
    """Score every kept checkpoint from `from_step` on (resumable), write the ranking, copy the winner."""
    if rollout_noise is not None:  # the same checks as the benches' and rollout's flags
        checks.number("--rollout-noise", rollout_noise, lo=0.0, hi=MAX_ROLLOUT_NOISE)
    if advection_correction is not None:
        checks.number("--advection-correction", advection_correction, lo=0.0, hi=1.0)
    if not seeds or any(s < 0 for s in seeds):
        raise ConfigError(f"--seeds {list(seeds)}: give one or more rollout seeds >= 0 (e.g. --seeds 0 1)")
    ckpts = step_checkpoints(run_dir, from_step)
    sel = run_dir / "selection" / options_tag(rollout_noise, advection_correction, mirror_alternate)
    rows = []
    for step, ckpt in ckpts.items():
        per_seed = []
        for seed in seeds:
            out = sel / f"step{step:06d}_seed{seed}" / "evaluation"  # where the tables look (fb-table)
            metrics = out / "metrics.json"
            if not metrics.is_file():
                metrics = evaluator(ckpt, out, rollout_overrides(rollout_noise, advection_correction, seed,
                                                                 mirror_alternate))
            per_seed.append(pooled_score(json.loads(metrics.read_text()), metrics))
        mean = {k: float(np.mean([s[k] for s in per_seed])) for k in (*SCORE_KEYS, "sum")}
        rows.append({"step": step, "checkpoint": str(ckpt), **mean, "sum_per_seed": [s["sum"] for s in per_seed]})
    best = min(rows, key=lambda r: (r["sum"], -r["step"]))  # a tie goes to the longer-trained net
    target = run_dir / "checkpoints" / SELECTED
    tmp = target.with_suffix(".tmp")
    shutil.copyfile(best["checkpoint"], tmp)
    tmp.replace(target)
    doc = {"run_dir": str(run_dir), "from_step": from_step, "rollout_noise": rollout_noise,
           "advection_correction": advection_correction, "mirror_alternate": mirror_alternate,
           "seeds": list(seeds), "rows": rows,
           "selected": {"step": best["step"], "checkpoint": best["checkpoint"], "copied_to": str(target)},
           "date_utc": datetime.now(UTC).isoformat(timespec="seconds")}
    atomic_write_json(sel / "selection.json", doc)
    (sel / "selection.md").write_text(render(doc))
    return doc


def render(doc: dict) -> str:
    def opt(key: str) -> str:
        return "as trained" if doc[key] is None else f"{doc[key]:g}"

    mirror = {None: "as trained", True: "on", False: "off"}[doc.get("mirror_alternate")]
    opts = (f"rollout noise {opt('rollout_noise')}, advection correction {opt('advection_correction')}, "
            f"mirror-alternating steps {mirror}, rollout seeds {doc['seeds']}")
    lines = [f"# Checkpoint selection: {doc['run_dir']}", "",
             f"Validation part, 3000-step rollouts, {opts}; pooled against every CFD-DEM run at each velocity, "
             "means over the velocities (and seeds). Selected: step "
             f"{doc['selected']['step']} -> {doc['selected']['copied_to']}.", "",
             "| step | rel. L2 mean solid fraction | rel. L2 std solid fraction | Lacey MAE | sum | sum per seed |",
             "|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        mark = " **selected**" if r["step"] == doc["selected"]["step"] else ""
        lines.append(f"| {r['step']}{mark} | {r[SCORE_KEYS[0]]:.3f} | {r[SCORE_KEYS[1]]:.3f} | {r[SCORE_KEYS[2]]:.3f} "
                     f"| {r['sum']:.3f} | {' / '.join(f'{s:.3f}' for s in r['sum_per_seed'])} |")
    return "\n".join(lines) + "\n"


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = doc_parser("neuraldem.scenes.fluidized_bed.select", __doc__)
    p.add_argument("run_dir", type=Path, help="a fluidized-bed training run (hydra.run.dir of neuraldem.train)")
    p.add_argument("--from-step", type=int, default=0, help="skip checkpoints before this training step")
    p.add_argument("--rollout-noise", type=float, default=None,
                   help="fluidized_bed.rollout_noise (default: as trained)")
    p.add_argument("--advection-correction", type=float, default=None,
                   help="fluidized_bed.advection_correction (default: as trained)")
    p.add_argument("--mirror-alternate", action="store_true", default=None,
                   help="fluidized_bed.mirror_alternate=true (default: as trained)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="rollout seeds to average over")
    a = p.parse_args(argv)
    doc = select(a.run_dir, a.from_step, a.rollout_noise, a.advection_correction, a.seeds,
                 mirror_alternate=a.mirror_alternate)
    print(render(doc), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
