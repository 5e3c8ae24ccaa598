"""`neuraldem datagen data=hopper_small n_sims=200 workers=2`

Runs the real solver for every simulation of a dataset that is not finished yet, side by side on
`workers` cores (serial solver processes; MPI on few cores only burns CPU), and keeps the manifest up to
date after every simulation. Kill it any time and start it again: finished simulations are kept.

`executor=slurm executor.partition=... executor.array_parallelism=...` runs them as a Slurm job array instead
(`executor.dry_run=true` writes its sbatch script only), `executor=submitit_local` as separate processes here
(neuraldem.datagen.executors, docs/cluster_datagen.md).
"""

from __future__ import annotations

import logging
from collections import Counter
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from neuraldem.cli import hydra_app
from neuraldem.config import checks
from neuraldem.data.manifest import Manifest
from neuraldem.datagen.driver import DatagenOptions, Pipeline, generate
from neuraldem.datagen.executors import ExecutorSettings, dry_run, make_runner, require_backend
from neuraldem.errors import ConfigError
from neuraldem.machine import cpu_count
from neuraldem.scenes import scene

log = logging.getLogger("neuraldem.datagen")


def make_pipeline(data_cfg: DictConfig) -> Pipeline:
    return scene(data_cfg.get("kind")).pipeline(data_cfg)


def summary_lines(m: Manifest, n_sims: int) -> list[str]:
    recs = m.simulations[:n_sims]
    status = Counter(r.status for r in recs)
    lines = [f"{m.name}: {n_sims} simulations: " + ", ".join(f"{v} {k}" for k, v in sorted(status.items()))]
    cpu = [r.cost["cpu_s"] for r in recs if r.usable and "cpu_s" in r.cost]
    if cpu:
        lines.append(f"solver CPU s per simulation: median {np.median(cpu):.1f} (min {min(cpu):.1f}, "
                     f"max {max(cpu):.1f})")
    char = [r.cost["characterization_cpu_s"] for r in recs if "characterization_cpu_s" in r.cost]
    if char:
        lines.append(f"characterization CPU s per parameter set: median {np.median(char):.1f}")
    steps = [r.cost["particle_steps"] / r.cost["cpu_s"] for r in recs
             if r.usable and r.cost.get("cpu_s") and "particle_steps" in r.cost]
    if steps:
        lines.append(f"particle-steps per CPU-second: median {np.median(steps):.3g}")
    keys = sorted({k for r in recs if r.usable for k, v in r.metrics.items() if isinstance(v, (int, float))})
    for key in keys:
        vals = [r.metrics[key] for r in recs if r.usable and key in r.metrics and np.isfinite(r.metrics[key])]
        if vals:
            lines.append(f"{key}: {min(vals):.3g} .. {max(vals):.3g} (median {np.median(vals):.3g})")
    return lines


def first_ids(value: object) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, str):
        return (value,)
    try:
        ids = tuple(str(v) for v in value)  # type: ignore[union-attr]
    except TypeError:
        raise ConfigError(f"config value first={value!r} is invalid: give simulation ids, "
                          "e.g. first=[sim_0091]") from None
    return ids


@hydra_app("datagen")
def main(cfg: DictConfig) -> None:
    n_sims = checks.positive_int("n_sims", cfg.n_sims)
    workers = checks.positive_int("workers", cfg.workers)
    executor = ExecutorSettings.from_config(cfg.get("executor"))
    require_backend(executor)
    parallel = workers if executor.kind == "local" else executor.array_parallelism
    if executor.kind != "slurm" and parallel > cpu_count():
        log.warning("%d simulations at a time > %d cores: runs will share cores and each gets slower", parallel,
                    cpu_count())
    pipe = make_pipeline(cfg.data)
    few = getattr(pipe, "split_warning", lambda n: None)(n_sims)
    if few:
        log.warning(few)
    run_dir = Path(cfg.paths.output_dir)
    opts = DatagenOptions(n_sims=n_sims, workers=workers, retry_failed=bool(cfg.retry_failed),
                          progress=bool(cfg.progress), first=first_ids(cfg.get("first")),
                          runner=make_runner(executor, run_dir))
    if executor.dry_run:
        dry_run(pipe, opts, executor, run_dir)
        return
    m = generate(pipe, opts)
    for line in summary_lines(m, n_sims):
        print(line)


if __name__ == "__main__":
    main()
