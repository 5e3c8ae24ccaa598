"""`python -m neuraldem.evaluate ckpt=PATH`: a trained model against its solver on held-out simulations.

The checkpoint says what it is. A fluidized-bed model is scored by `neuraldem.eval.fb_eval`: one rollout per
held-out inlet velocity against CFD-DEM (time statistics, mass drift, Lacey curves, stability at 1x, 3x, 10x
the training horizon; options under `fluidized_bed:`), into metrics.json, report.md, PNG figures and VTK.
A refilling-hopper model is scored by `neuraldem.eval.refill_eval` (transport `refill.horizon` seconds after
a reference time, residence-time distribution at the outlet over a rollout with periodic reference resets;
options under `refill:`). A hopper model: for each simulation of the chosen split part, the model is rolled over the whole trajectory
from the scalars alone, its occupancy and transport fields are evaluated at the initial particle positions,
and the same functions that scored the DEM data compute drainage time, residual, outflow, flow regime,
stripes and residence time. Writes metrics.json, table.md (layout of the paper's Table 4), PNG figures and
VTK files into the run folder, and prints the table.
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from neuraldem.cli import hydra_app
from neuraldem.config import checks
from neuraldem.eval.checkpoints import checkpoint_metadata
from neuraldem.eval.hopper_report import TABLE_HEADER, evaluate_checkpoint


@hydra_app("evaluate")
def main(cfg: DictConfig) -> None:
    checks.required(cfg, "evaluate", {"ckpt": "ckpt=<run>/checkpoints/last.ckpt"})
    checks.one_of("part", cfg.part, ("train", "val", "test"))
    checks.fraction("threshold", cfg.threshold)
    checks.one_of("device", cfg.device, ("auto", "cpu", "cuda"))
    if cfg.max_sims is not None:
        checks.positive_int("max_sims", cfg.max_sims)
    kind = checkpoint_metadata(Path(cfg.ckpt))["kind"]
    if kind == "fluidized_bed":
        evaluate_fluidized_bed(cfg)
        return
    if kind == "hopper_refill":
        evaluate_refill(cfg)
        return
    result = evaluate_checkpoint(
        Path(cfg.ckpt), out_dir=Path(cfg.paths.output_dir), datasets_dir=Path(cfg.paths.datasets_dir),
        dataset_dir=cfg.dataset_dir, split=cfg.split, part=cfg.part, max_sims=cfg.max_sims,
        threshold=cfg.threshold, vtk=cfg.vtk, device=cfg.device)
    print(TABLE_HEADER)
    print("\n".join(result["table_rows"]))
    agg = result["aggregate"]
    print(f"{agg['n_sims']} {cfg.part} simulations: drainage t95 MAE {agg['drainage_t95_mae_s']:.3f} s "
          f"({agg['drainage_t95_pct_of_mean']:.1f} % of the mean; 1 % rule {agg['drainage_mae_pct_of_mean']:.1f} %), "
          f"residual MAE {agg['residual_mae_pp']:.2f} pp, "
          f"outflow error {agg['outflow_rel_err_pct']:.1f} %, flow regime accuracy "
          f"{100 * agg['flow_regime_accuracy']:.0f} %")
    print(f"results in {cfg.paths.output_dir}")


def evaluate_refill(cfg: DictConfig) -> None:
    from neuraldem.eval.hopper_report import resolve_device
    from neuraldem.eval.refill_eval import evaluate_refill_checkpoint

    r = cfg.refill
    t_ref = None if r.t_ref is None else checks.number("refill.t_ref", r.t_ref, lo=0.0)
    horizon = None if r.horizon is None else checks.positive("refill.horizon", r.horizon)
    result = evaluate_refill_checkpoint(
        Path(cfg.ckpt), out_dir=Path(cfg.paths.output_dir), datasets_dir=Path(cfg.paths.datasets_dir),
        dataset_dir=cfg.dataset_dir, split=cfg.split, part=cfg.part, max_sims=cfg.max_sims, t_ref=t_ref,
        horizon=horizon, threshold=cfg.threshold, time_stride=checks.positive_int("refill.time_stride", r.time_stride),
        device=resolve_device(cfg.device), vtk=checks.boolean("vtk", cfg.vtk),
        new_tolerance=None if r.new_tolerance is None else checks.number("refill.new_tolerance", r.new_tolerance, lo=0.0))
    agg = result["aggregate"]
    print(f"{agg['n_sims']} {cfg.part} simulations, transport {result['horizon']:g} s after t_ref: layer-fraction "
          f"error {agg['layer_fraction_error']:.3f}, label agreement {agg['label_agreement']:.2f}, transport MSE "
          f"{agg['transport_mse']:.2e}, residence MSE {agg['residence_mse']:.2e}; outlet residence-time "
          f"distribution: Wasserstein {agg['rtd_wasserstein_s']:.3f} s, median error {agg['rtd_median_error_s']:+.3f} s")
    base = result["persistence"]
    print(f"persistence (nothing moved since t_ref), same scoring: layer-fraction error "
          f"{base['layer_fraction_error']:.3f}, label agreement {base['label_agreement']:.2f}, transport MSE "
          f"{base['transport_mse']:.2e}, residence MSE {base['residence_mse']:.2e}, RTD Wasserstein "
          f"{base['rtd_wasserstein_s']:.3f} s")
    print(f"results in {cfg.paths.output_dir}")


def evaluate_fluidized_bed(cfg: DictConfig) -> None:
    from neuraldem.eval.fb_eval import evaluate_checkpoint as evaluate_fb
    from neuraldem.eval.fb_rollout import DivergenceLimits
    from neuraldem.lit.fb_stability import MIXING_MODES

    fb = cfg.fluidized_bed
    result = evaluate_fb(
        Path(cfg.ckpt), out_dir=Path(cfg.paths.output_dir), datasets_dir=Path(cfg.paths.datasets_dir),
        dataset_dir=cfg.dataset_dir, split=cfg.split, part=cfg.part, max_sims=cfg.max_sims,
        horizons=list(fb.horizons), limits=DivergenceLimits(fb.max_packing, fb.tolerance),
        seed=checks.positive_int("fluidized_bed.seed", fb.seed, allow_zero=True), vtk=cfg.vtk, device=cfg.device,
        conserve_solid_volume=None if fb.conserve_solid_volume is None else checks.boolean(
            "fluidized_bed.conserve_solid_volume", fb.conserve_solid_volume),
        mixing=None if fb.get("mixing") is None else checks.one_of("fluidized_bed.mixing", fb.mixing, MIXING_MODES),
        init_snapshot=checks.positive_int("fluidized_bed.init_snapshot", fb.get("init_snapshot", 1), allow_zero=True),
        advection_correction=None if fb.get("advection_correction") is None else checks.number(
            "fluidized_bed.advection_correction", fb.advection_correction, lo=0.0, hi=1.0))
    agg = result["aggregate"]
    print((Path(cfg.paths.output_dir) / "report.md").read_text())
    print(f"{agg['n_trajectories']} held-out velocities: mean solid-fraction rel. L2 "
          f"{agg['solid_fraction_mean_rel_l2']:.3f}, max mass drift {agg['mass_max_abs_drift_pct']:.2f} % over "
          f"{result['rollout_steps']} steps, Lacey MAE {agg['lacey_mae']:.3f}")
    print(f"results in {cfg.paths.output_dir}")


if __name__ == "__main__":
    main()
