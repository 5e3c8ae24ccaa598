"""The hopper (LIGGGHTS discharge): particles drain through an orifice; scored by drainage time, residual,
outflow, flow regime, stripes and residence time (`neuraldem.scenes.hopper.evaluation`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from neuraldem.scenes import Scene


def pipeline(data_cfg: DictConfig) -> Any:
    from neuraldem.scenes.hopper.datagen import HopperPipeline

    return HopperPipeline(data_cfg)


def print_table(result: dict[str, Any]) -> None:
    from neuraldem.scenes.hopper.evaluation import TABLE_HEADER

    print(TABLE_HEADER)
    print("\n".join(result["table_rows"]))


def evaluate(cfg: DictConfig) -> None:
    from neuraldem.scenes.hopper.evaluation import evaluate_checkpoint

    result = evaluate_checkpoint(
        Path(cfg.ckpt), out_dir=Path(cfg.paths.output_dir), datasets_dir=Path(cfg.paths.datasets_dir),
        dataset_dir=cfg.dataset_dir, split=cfg.split, part=cfg.part, max_sims=cfg.max_sims,
        threshold=cfg.threshold, vtk=cfg.vtk, device=cfg.device)
    print_table(result)
    agg = result["aggregate"]
    print(f"{agg['n_sims']} {cfg.part} simulations: drainage t95 MAE {agg['drainage_t95_mae_s']:.3f} s "
          f"({agg['drainage_t95_pct_of_mean']:.1f} % of the mean; 1 % rule {agg['drainage_mae_pct_of_mean']:.1f} %), "
          f"residual MAE {agg['residual_mae_pp']:.2f} pp, "
          f"outflow error {agg['outflow_rel_err_pct']:.1f} %, flow regime accuracy "
          f"{100 * agg['flow_regime_accuracy']:.0f} %")
    if result["skipped"]:
        print(f"{len(result['skipped'])} run(s) not evaluated (query points outside the trained box): "
              f"{', '.join(s['sim_id'] for s in result['skipped'])}")
    print(f"results in {cfg.paths.output_dir}")


def evaluate_run(cfg: DictConfig, ckpt: Path) -> dict[str, Any]:
    from neuraldem.scenes.hopper.evaluation import evaluate_checkpoint

    result = evaluate_checkpoint(ckpt, out_dir=Path(cfg.paths.output_dir) / "evaluation",
                                 datasets_dir=Path(cfg.paths.datasets_dir), dataset_dir=cfg.data.dataset_dir,
                                 progress=False)
    print_table(result)
    return result


SCENE = Scene(kind="hopper", description="LIGGGHTS hopper discharge", experiment="experiment=hopper_micro",
              pipeline=pipeline, evaluate=evaluate, evaluate_run=evaluate_run)
