"""`python -m neuraldem.rollout ckpt=PATH velocity=V steps=N`: autoregressive rollout of a fluidized-bed model.

Starts from the first snapshot of a dataset trajectory (or `init=FILE`), feeds the model its own predictions
for N steps (particles re-sampled from the predicted solid fraction each step), stops at the first unphysical
state (NaN/inf, solid fraction out of [0, max_packing]) and names the step. Writes rollout.h5 (the grid
fields under the dataset's names), rollout.json and a ParaView series (vtk/*.pvd) into the run folder.
Exit status: 0 finished, 1 diverged (the states before the divergence are written), 2 bad input.
"""

from __future__ import annotations

import sys
from pathlib import Path

from omegaconf import DictConfig

from neuraldem.cli import hydra_app
from neuraldem.config import checks
from neuraldem.eval.checkpoints import resolve_device
from neuraldem.scenes.fluidized_bed.rollout import DivergenceLimits, run_rollout
from neuraldem.scenes.fluidized_bed.stability import MIXING_MODES, check_rollout_value


@hydra_app("rollout")
def main(cfg: DictConfig) -> None:
    checks.required(cfg, "rollout", {"ckpt": "ckpt=<run>/checkpoints/last.ckpt", "velocity": "velocity=1.6"})
    checks.one_of("device", cfg.device, ("auto", "cpu", "cuda"))
    limits = DivergenceLimits(checks.number("max_packing", cfg.max_packing, lo=0.0, hi=1.0, lo_open=True),
                              checks.number("tolerance", cfg.tolerance, lo=0.0, hi=0.5))
    summary = run_rollout(
        Path(cfg.ckpt), checks.positive("velocity", cfg.velocity), checks.positive_int("steps", cfg.steps),
        out_dir=Path(cfg.paths.output_dir), datasets_dir=Path(cfg.paths.datasets_dir),
        dataset_dir=cfg.dataset_dir, init=cfg.init, init_sim=cfg.init_sim, init_snapshot=cfg.init_snapshot,
        seed=checks.positive_int("seed", cfg.seed, allow_zero=True), limits=limits,
        particles_every=cfg.particles_every, vtk=bool(cfg.vtk), vtk_every=cfg.vtk_every,
        device=resolve_device(cfg.device), progress=bool(cfg.progress),
        conserve_solid_volume=None if cfg.conserve_solid_volume is None else checks.boolean(
            "conserve_solid_volume", cfg.conserve_solid_volume),
        mixing=None if cfg.get("mixing") is None else checks.one_of("mixing", cfg.mixing, MIXING_MODES),
        mirror_alternate=None if cfg.get("mirror_alternate") is None else checks.boolean(
            "mirror_alternate", cfg.mirror_alternate),
        rollout_noise=None if cfg.get("rollout_noise") is None else check_rollout_value(
            "rollout_noise", cfg.rollout_noise),
        advection_correction=None if cfg.get("advection_correction") is None else check_rollout_value(
            "advection_correction", cfg.advection_correction))
    print(summary["message"])
    if summary["extrapolation"]:
        lo, hi = summary["trained_velocity_range"]
        print(f"note: {cfg.velocity} m/s is outside the trained range [{lo:g}, {hi:g}] m/s (extrapolation)")
    print(f"results in {cfg.paths.output_dir}")
    if summary["diverged_at"] is not None:
        sys.exit(1)


if __name__ == "__main__":
    main()
