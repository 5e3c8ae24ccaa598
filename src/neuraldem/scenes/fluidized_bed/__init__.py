"""The fluidized bed (OpenFOAM DPMFoam, CFD-DEM): scored by time statistics, bubbles, Lacey mixing, solid
volume and rollout stability against CFD-DEM (`neuraldem.scenes.fluidized_bed.analysis.evaluation`)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from neuraldem.config import checks
from neuraldem.scenes import Scene
from neuraldem.scenes.fluidized_bed.parameters import PARAMETERS
from neuraldem.scenes.fluidized_bed.surrogate.option_aliases import RENAMED_OVERRIDES

if TYPE_CHECKING:
    from omegaconf import DictConfig  # the configs a scene is handed; imported only for type checks


def pipeline(data_cfg: DictConfig) -> Any:
    from neuraldem.scenes.fluidized_bed.dataset.datagen import BedPipeline

    return BedPipeline(data_cfg)


def evaluate(cfg: DictConfig) -> None:
    from neuraldem.scenes.fluidized_bed.analysis.evaluation import evaluate_checkpoint
    from neuraldem.scenes.fluidized_bed.surrogate.options import RolloutOptions
    from neuraldem.scenes.fluidized_bed.surrogate.rollout import DivergenceLimits

    fb = cfg.fluidized_bed
    result = evaluate_checkpoint(
        Path(cfg.ckpt), out_dir=Path(cfg.paths.output_dir), datasets_dir=Path(cfg.paths.datasets_dir),
        dataset_dir=cfg.dataset_dir, split=cfg.split, part=cfg.part, max_sims=cfg.max_sims,
        horizons=list(fb.horizons), limits=DivergenceLimits(fb.max_packing, fb.tolerance),
        seed=checks.positive_int("fluidized_bed.seed", fb.seed, allow_zero=True), vtk=cfg.vtk, device=cfg.device,
        init_snapshot=checks.positive_int("fluidized_bed.init_snapshot", fb.get("init_snapshot", 1), allow_zero=True),
        options=RolloutOptions.from_config(cfg.get("rollout")))
    agg = result["aggregate"]
    print((Path(cfg.paths.output_dir) / "report.md").read_text())
    which = "held-out velocities" if cfg.part == "test" else f"{cfg.part} trajectories"
    print(f"{agg['n_trajectories']} {which}: mean solid-fraction rel. L2 "
          f"{agg['solid_fraction_mean_rel_l2']:.3f}, max mass drift {agg['mass_max_abs_drift_pct']:.2f} % over "
          f"{result['rollout_steps']} steps, Lacey MAE {agg['lacey_mae']:.3f}")
    print(f"results in {cfg.paths.output_dir}")


def evaluate_run(cfg: DictConfig, ckpt: Path) -> dict[str, Any]:
    from neuraldem.scenes.fluidized_bed.analysis.evaluation import evaluate_checkpoint

    out = Path(cfg.paths.output_dir) / "evaluation"
    result = evaluate_checkpoint(ckpt, out_dir=out, datasets_dir=Path(cfg.paths.datasets_dir),
                                 dataset_dir=cfg.data.dataset_dir, progress=False)
    print((out / "report.md").read_text())
    return result


def rollout(cfg: DictConfig) -> bool:
    """False when the rollout diverged (`neuraldem evaluate rollout` then exits 1)."""
    from neuraldem.scenes.fluidized_bed.surrogate.rollout_run import rollout_command

    return rollout_command(cfg)


SCENE = Scene(
    kind="fluidized_bed", description="OpenFOAM DPMFoam fluidized bed (CFD-DEM)", experiment="experiment=fb",
    renamed_keys=RENAMED_OVERRIDES,  # the rollout options' old keys (surrogate/option_aliases.py)
    parameters=PARAMETERS, pipeline=pipeline, evaluate=evaluate, evaluate_run=evaluate_run, rollout=rollout,
    module="neuraldem.scenes.fluidized_bed.surrogate.module:BedModule", aliases=("bed", "fb"),
    whatif="neuraldem.scenes.fluidized_bed.predict", page="neuraldem.scenes.fluidized_bed.explorer.page",
    release="neuraldem.scenes.fluidized_bed.release", scene_keys="neuraldem.scenes.fluidized_bed.scene_keys:SCENE_KEYS",
    benchmarks={
        "fb_speed": ("neuraldem.scenes.fluidized_bed.bench.speed",
                     "DPMFoam vs the fluidized-bed rollout per simulated second, side by side (speed-up ratios)"),
        "fb_speed_accuracy": ("neuraldem.scenes.fluidized_bed.bench.speed_accuracy",
                              "rollout cost vs error of time averages and mixing, surrogates and cheaper DPMFoam; "
                              "Pareto front, right-sizing"),
        "fb_runtime": ("neuraldem.scenes.fluidized_bed.bench.runtime",
                       "torch vs ONNX Runtime stepping the shipped bed model: answer time, answers within the "
                       "seed spread"),
        "fb_batch": ("neuraldem.scenes.fluidized_bed.bench.batch",
                     "one forward pass for several bed rollouts (the explorer's lattice, an ensemble) against one "
                     "each: time per member"),
        "fb_stability": ("neuraldem.scenes.fluidized_bed.bench.stability_map",
                         "stability map: divergence, solid volume and bed height against CFD-DEM across velocities"),
        "whatif_fb": ("neuraldem.scenes.fluidized_bed.bench.predict_timing",
                      "neuraldem predict fluidized_bed: answer times, and GP / field model vs DPMFoam where "
                      "verify=true checked"),
    },
    reports={
        "fb-dataset": ("neuraldem.scenes.fluidized_bed.dataset.report",
                       "ground-truth report of a fluidized-bed dataset"),
        "fb-table": ("neuraldem.scenes.fluidized_bed.analysis.table", "fluidized-bed runs and baselines side by side"),
        "fb-select": ("neuraldem.scenes.fluidized_bed.surrogate.selection",
                      "choose a bed checkpoint on long validation rollouts"),
        "fb-baselines": ("neuraldem.scenes.fluidized_bed.analysis.baselines",
                         "nearest / interpolated / constant CFD-DEM baselines"),
        "fb-reference-floor": ("neuraldem.scenes.fluidized_bed.analysis.reference_floor",
                               "how well short CFD-DEM series estimate long-run statistics"),
        "advection-oracle": ("neuraldem.scenes.fluidized_bed.analysis.advection_oracle",
                             "mixing advection with CFD-DEM's own fields"),
    },
    importer=("foam", "neuraldem.scenes.fluidized_bed.dataset.importer",
              "OpenFOAM DPMFoam cases of your own fluidized beds as a dataset"),
    # a bed model steps by the snapshot interval and reads kernel fields: both must be the ones it learned
    import_match_keys=("fluidized_bed.width", "fluidized_bed.thickness", "fluidized_bed.height",
                       "fluidized_bed.cells", "fluidized_bed.diameter", "fluidized_bed.density",
                       "fluidized_bed.snapshot_interval", "fields.kernel_sigma", "fields.mixing_sigma"),
)
