"""The hopper (LIGGGHTS discharge): particles drain through an orifice; scored by drainage time, residual,
outflow, flow regime, stripes and residence time (`neuraldem.scenes.hopper.analysis.evaluation`)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from neuraldem.scenes import Scene
from neuraldem.scenes.hopper.parameters import PARAMETERS

if TYPE_CHECKING:
    from omegaconf import DictConfig  # the configs a scene is handed; imported only for type checks


def pipeline(data_cfg: DictConfig) -> Any:
    from neuraldem.scenes.hopper.dataset.datagen import HopperPipeline

    return HopperPipeline(data_cfg)


def print_table(result: dict[str, Any]) -> None:
    from neuraldem.scenes.hopper.analysis.evaluation import TABLE_HEADER

    print(TABLE_HEADER)
    print("\n".join(result["table_rows"]))


def evaluate(cfg: DictConfig) -> None:
    from neuraldem.scenes.hopper.analysis.evaluation import evaluate_checkpoint

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
    from neuraldem.scenes.hopper.analysis.evaluation import evaluate_checkpoint

    result = evaluate_checkpoint(ckpt, out_dir=Path(cfg.paths.output_dir) / "evaluation",
                                 datasets_dir=Path(cfg.paths.datasets_dir), dataset_dir=cfg.data.dataset_dir,
                                 progress=False)
    print_table(result)
    return result


SCENE = Scene(
    kind="hopper", description="LIGGGHTS hopper discharge", experiment="experiment=hopper_micro",
    parameters=PARAMETERS, pipeline=pipeline, evaluate=evaluate, evaluate_run=evaluate_run,
    module="neuraldem.scenes.hopper.surrogate.module:HopperModule",
    whatif="neuraldem.scenes.hopper.predict", scan="neuraldem.scenes.hopper.scan",
    page="neuraldem.scenes.hopper.explorer.page", release="neuraldem.scenes.hopper.release",
    scene_keys="neuraldem.scenes.hopper.scene_keys:SCENE_KEYS",
    benchmarks={
        "hopper_speed": ("neuraldem.scenes.hopper.bench.speed",
                         "LIGGGHTS vs the hopper surrogate on the same questions, side by side (speed-up ratios)"),
        "hopper_scaling": ("neuraldem.scenes.hopper.bench.scaling",
                           "LIGGGHTS cost vs particle count; surrogate cost vs query points and latent tokens"),
        "seed_floor": ("neuraldem.scenes.hopper.bench.seed_floor",
                       "LIGGGHTS rerun with other packing seeds: the noise floor of every hopper quantity"),
        "query_budget": ("neuraldem.scenes.hopper.bench.query_budget",
                         "the field model's errors against answer time over its query budget (lattice, times)"),
        "runtime": ("neuraldem.scenes.hopper.bench.runtime",
                    "what runs the field model fastest: eager torch, torch.compile, ONNX Runtime (threads)"),
        "whatif": ("neuraldem.scenes.hopper.bench.predict_timing",
                   "neuraldem predict hopper: answer times, and GP / field model vs LIGGGHTS at random points"),
    },
    reports={
        "hopper-table": ("neuraldem.scenes.hopper.analysis.table", "hopper runs side by side"),
        "hopper-cv": ("neuraldem.scenes.hopper.analysis.cv",
                      "the hopper table cross-validated (model, constant, GP, seed floor)"),
        "occupancy": ("neuraldem.scenes.hopper.dataset.occupancy_coverage",
                      "how well the occupancy field counts hopper material"),
        "hopper-diagnosis": ("neuraldem.scenes.hopper.analysis.diagnosis",
                             "where a hopper field model's answer errors come from, on its validation runs"),
    },
    exports={"pack": ("neuraldem.scenes.hopper.dataset.transfer",
                      "a compact, exact copy of a hopper dataset in parts, for moving it to a training machine"),
             "unpack": ("neuraldem.scenes.hopper.dataset.transfer", "a packed hopper dataset back as a dataset")},
    importer=("liggghts", "neuraldem.scenes.hopper.dataset.importer",
              "LIGGGHTS dump files of your own hopper runs as a dataset"),
    import_match_keys=("hopper.hopper_diameter", "hopper.outlet_diameter", "hopper.material.diameter"),
    import_report_keys=("hopper.material.dt",),
)
