"""`python -m neuraldem.evaluate ckpt=PATH`: a hopper model against DEM on held-out simulations.

For each simulation of the chosen split part, the model is rolled over the whole trajectory from the
scalars alone, its occupancy and transport fields are evaluated at the initial particle positions, and the
same functions that scored the DEM data compute drainage time, residual, outflow, flow regime, stripes and
residence time. Writes metrics.json, table.md (layout of the paper's Table 4), PNG figures and VTK files
into the run folder, and prints the table.
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from neuraldem.cli import hydra_app
from neuraldem.config import checks
from neuraldem.eval.hopper_report import TABLE_HEADER, evaluate_checkpoint


@hydra_app("evaluate")
def main(cfg: DictConfig) -> None:
    checks.one_of("part", cfg.part, ("train", "val", "test"))
    checks.fraction("threshold", cfg.threshold)
    checks.one_of("device", cfg.device, ("auto", "cpu", "cuda"))
    if cfg.max_sims is not None:
        checks.positive_int("max_sims", cfg.max_sims)
    result = evaluate_checkpoint(
        Path(cfg.ckpt), out_dir=Path(cfg.paths.output_dir), datasets_dir=Path(cfg.paths.datasets_dir),
        dataset_dir=cfg.dataset_dir, split=cfg.split, part=cfg.part, max_sims=cfg.max_sims,
        threshold=cfg.threshold, vtk=cfg.vtk, device=cfg.device)
    print(TABLE_HEADER)
    print(result["table_row"])
    agg = result["aggregate"]
    print(f"{agg['n_sims']} {cfg.part} simulations: drainage MAE {agg['drainage_mae_s']:.3f} s "
          f"({agg['drainage_mae_pct_of_mean']:.1f} % of the mean), residual MAE {agg['residual_mae_pp']:.2f} pp, "
          f"outflow error {agg['outflow_rel_err_pct']:.1f} %, flow regime accuracy "
          f"{100 * agg['flow_regime_accuracy']:.0f} %")
    print(f"results in {cfg.paths.output_dir}")


if __name__ == "__main__":
    main()
