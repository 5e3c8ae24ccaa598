"""`neuraldem evaluate ckpt=PATH`: a trained model against its solver on held-out simulations.

The checkpoint says what it is; its scene (`neuraldem.scenes`) scores it. A fluidized-bed model is scored by
`neuraldem.scenes.fluidized_bed.analysis.evaluation`: one rollout per held-out inlet velocity against CFD-DEM (time
statistics,
mass drift, Lacey curves, stability at 1x, 3x, 10x the training horizon; options under `fluidized_bed:`, the
rollout options as on every command, `rollout.<name>=`, conf/rollout/), into
metrics.json, report.md, PNG figures and VTK. A refilling-hopper model is scored by
`neuraldem.scenes.hopper_refill.evaluation` (transport `refill.horizon` seconds after a reference time, residence-time
distribution at the outlet over a rollout with periodic reference resets; options under `refill:`). A hopper
model: for each simulation of the chosen split part, the model is rolled over the whole trajectory from the
scalars alone, its occupancy and transport fields are evaluated at the initial particle positions, and the
same functions that scored the DEM data compute drainage time, residual, outflow, flow regime, stripes and
residence time. Writes metrics.json, table.md (layout of the paper's Table 4), PNG figures and VTK files into
the run folder, and prints the table. A GNS (particle) checkpoint is rolled out on one stored run with its
stability checks (options under `gns:`). (`python -m neuraldem.evaluate` runs the same code.)
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from neuraldem.cli import hydra_app
from neuraldem.config import checks
from neuraldem.eval.checkpoints import checkpoint_metadata
from neuraldem.scenes import scene


@hydra_app("evaluate")
def main(cfg: DictConfig) -> None:
    checks.required(cfg, "evaluate", {"ckpt": "ckpt=<run>/checkpoints/last.ckpt"})
    checks.one_of("part", cfg.part, ("train", "val", "test"))
    checks.fraction("threshold", cfg.threshold)
    checks.one_of("device", cfg.device, ("auto", "cpu", "cuda"))
    if cfg.max_sims is not None:
        checks.positive_int("max_sims", cfg.max_sims)
    kind = checkpoint_metadata(Path(cfg.ckpt))["kind"]
    if kind == "gns":  # the particle-based baseline: one model kind for both scenes
        evaluate_gns(cfg)
        return
    scene(kind, key=f"the kind of checkpoint {cfg.ckpt}").evaluate(cfg)


def evaluate_gns(cfg: DictConfig) -> None:
    """A GNS rolled out on one stored run with its stability checks and scored with the scene's metrics
    (`neuraldem.gns.rollout`): gns_rollout.json and .h5 in the run folder."""
    from neuraldem.gns.rollout import run_gns_rollout

    g = cfg.gns
    steps = None if g.steps is None else checks.positive_int("gns.steps", g.steps)
    result = run_gns_rollout(Path(cfg.ckpt), Path(cfg.paths.output_dir), g.sim, steps, cfg.dataset_dir)
    state = f"failed at step {result['steps_to_failure']}: {result['failure']}" if result["failed"] else "stable"
    print(f"{result['sim_id']}: {result['steps_done']} of {result['steps_requested']} steps, {state}")
    print(f"results in {cfg.paths.output_dir}")


if __name__ == "__main__":
    main()
