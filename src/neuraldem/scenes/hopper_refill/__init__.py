"""The refilling hopper (LIGGGHTS, inflow and outflow): scored by transport after a reference time and the
outlet residence-time distribution (`neuraldem.scenes.hopper_refill.evaluation`)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from neuraldem.config import checks
from neuraldem.scenes import Scene
from neuraldem.scenes.hopper.parameters import PARAMETERS as HOPPER_PARAMETERS  # the same solver, the same ranges

if TYPE_CHECKING:
    from omegaconf import DictConfig  # the configs a scene is handed; imported only for type checks


def pipeline(data_cfg: DictConfig) -> Any:
    from neuraldem.scenes.hopper_refill.datagen import RefillPipeline

    return RefillPipeline(data_cfg)


def evaluate(cfg: DictConfig) -> None:
    from neuraldem.eval.checkpoints import resolve_device
    from neuraldem.scenes.hopper_refill.evaluation import evaluate_refill_checkpoint

    r = cfg.refill
    t_ref = None if r.t_ref is None else checks.number("refill.t_ref", r.t_ref, lo=0.0)
    horizon = None if r.horizon is None else checks.positive("refill.horizon", r.horizon)
    new_tolerance = None if r.new_tolerance is None else checks.number("refill.new_tolerance", r.new_tolerance, lo=0.0)
    result = evaluate_refill_checkpoint(
        Path(cfg.ckpt), out_dir=Path(cfg.paths.output_dir), datasets_dir=Path(cfg.paths.datasets_dir),
        dataset_dir=cfg.dataset_dir, split=cfg.split, part=cfg.part, max_sims=cfg.max_sims, t_ref=t_ref,
        horizon=horizon, threshold=cfg.threshold, time_stride=checks.positive_int("refill.time_stride", r.time_stride),
        device=resolve_device(cfg.device), vtk=checks.boolean("vtk", cfg.vtk), new_tolerance=new_tolerance)
    agg = result["aggregate"]
    print(f"{agg['n_sims']} {cfg.part} simulations, transport {result['horizon']:g} s after t_ref: layer-fraction "
          f"error {agg['layer_fraction_error']:.3f}, label agreement {agg['label_agreement']:.2f}, transport MSE "
          f"{agg['transport_mse']:.2e}, residence MSE {agg['residence_mse']:.2e}; outlet residence-time "
          f"distribution: Wasserstein {agg['rtd_wasserstein_s']:.3f} s, "
          f"median error {agg['rtd_median_error_s']:+.3f} s")
    base = result["persistence"]
    print(f"persistence (nothing moved since t_ref), same scoring: layer-fraction error "
          f"{base['layer_fraction_error']:.3f}, label agreement {base['label_agreement']:.2f}, transport MSE "
          f"{base['transport_mse']:.2e}, residence MSE {base['residence_mse']:.2e}, RTD Wasserstein "
          f"{base['rtd_wasserstein_s']:.3f} s")
    print(f"results in {cfg.paths.output_dir}")


def evaluate_run(cfg: DictConfig, ckpt: Path) -> dict[str, Any]:
    from neuraldem.scenes.hopper_refill.evaluation import evaluate_refill_checkpoint

    return evaluate_refill_checkpoint(ckpt, out_dir=Path(cfg.paths.output_dir) / "evaluation",
                                      datasets_dir=Path(cfg.paths.datasets_dir), dataset_dir=cfg.data.dataset_dir)


SCENE = Scene(
    kind="hopper_refill", description="LIGGGHTS refilling hopper (inflow + outflow)",
    experiment="experiment=hopper_refill", parameters=HOPPER_PARAMETERS, pipeline=pipeline, evaluate=evaluate,
    evaluate_run=evaluate_run, module="neuraldem.scenes.hopper.surrogate.module:HopperModule",
    reports={"refill-table": ("neuraldem.scenes.hopper_refill.table", "refilling-hopper runs side by side")},
)
