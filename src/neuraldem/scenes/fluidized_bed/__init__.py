"""The fluidized bed (OpenFOAM DPMFoam, CFD-DEM): scored by time statistics, bubbles, Lacey mixing, solid
volume and rollout stability against CFD-DEM (`neuraldem.scenes.fluidized_bed.evaluation`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from neuraldem.config import checks
from neuraldem.scenes import Scene


def pipeline(data_cfg: DictConfig) -> Any:
    from neuraldem.scenes.fluidized_bed.datagen import FluidizedBedPipeline

    return FluidizedBedPipeline(data_cfg)


def evaluate(cfg: DictConfig) -> None:
    from neuraldem.scenes.fluidized_bed.evaluation import evaluate_checkpoint
    from neuraldem.scenes.fluidized_bed.rollout import DivergenceLimits
    from neuraldem.scenes.fluidized_bed.stability import ADVECTION_FLUXES, MIXING_MODES, check_rollout_value

    fb = cfg.fluidized_bed
    conserve = fb.conserve_solid_volume
    correction = fb.get("advection_correction")
    result = evaluate_checkpoint(
        Path(cfg.ckpt), out_dir=Path(cfg.paths.output_dir), datasets_dir=Path(cfg.paths.datasets_dir),
        dataset_dir=cfg.dataset_dir, split=cfg.split, part=cfg.part, max_sims=cfg.max_sims,
        horizons=list(fb.horizons), limits=DivergenceLimits(fb.max_packing, fb.tolerance),
        seed=checks.positive_int("fluidized_bed.seed", fb.seed, allow_zero=True), vtk=cfg.vtk, device=cfg.device,
        conserve_solid_volume=None if conserve is None else checks.boolean("fluidized_bed.conserve_solid_volume",
                                                                           conserve),
        mixing=None if fb.get("mixing") is None else checks.one_of("fluidized_bed.mixing", fb.mixing, MIXING_MODES),
        init_snapshot=checks.positive_int("fluidized_bed.init_snapshot", fb.get("init_snapshot", 1), allow_zero=True),
        advection_correction=None if correction is None else check_rollout_value(
            "advection_correction", correction, "fluidized_bed.advection_correction"),
        advection_flux=None if fb.get("advection_flux") is None else checks.one_of(
            "fluidized_bed.advection_flux", fb.advection_flux, ADVECTION_FLUXES),
        mirror_alternate=None if fb.get("mirror_alternate") is None else checks.boolean(
            "fluidized_bed.mirror_alternate", fb.mirror_alternate),
        rollout_noise=None if fb.get("rollout_noise") is None else check_rollout_value(
            "rollout_noise", fb.rollout_noise, "fluidized_bed.rollout_noise"))
    agg = result["aggregate"]
    print((Path(cfg.paths.output_dir) / "report.md").read_text())
    which = "held-out velocities" if cfg.part == "test" else f"{cfg.part} trajectories"
    print(f"{agg['n_trajectories']} {which}: mean solid-fraction rel. L2 "
          f"{agg['solid_fraction_mean_rel_l2']:.3f}, max mass drift {agg['mass_max_abs_drift_pct']:.2f} % over "
          f"{result['rollout_steps']} steps, Lacey MAE {agg['lacey_mae']:.3f}")
    print(f"results in {cfg.paths.output_dir}")


def evaluate_run(cfg: DictConfig, ckpt: Path) -> dict[str, Any]:
    from neuraldem.scenes.fluidized_bed.evaluation import evaluate_checkpoint

    out = Path(cfg.paths.output_dir) / "evaluation"
    result = evaluate_checkpoint(ckpt, out_dir=out, datasets_dir=Path(cfg.paths.datasets_dir),
                                 dataset_dir=cfg.data.dataset_dir, progress=False)
    print((out / "report.md").read_text())
    return result


SCENE = Scene(kind="fluidized_bed", description="OpenFOAM DPMFoam fluidized bed (CFD-DEM)", experiment="experiment=fb",
              pipeline=pipeline, evaluate=evaluate, evaluate_run=evaluate_run)
