"""`neuraldem evaluate ckpt=PATH`: a trained model against its solver on held-out simulations.

The checkpoint says what it is; its scene (`neuraldem.scenes`) scores it. A fluidized-bed model is scored by
`neuraldem.eval.fb_eval`: one rollout per held-out inlet velocity against CFD-DEM (time statistics, mass
drift, Lacey curves, stability at 1x, 3x, 10x the training horizon; options under `fluidized_bed:`), into
metrics.json, report.md, PNG figures and VTK. A refilling-hopper model is scored by
`neuraldem.eval.refill_eval` (transport `refill.horizon` seconds after a reference time, residence-time
distribution at the outlet over a rollout with periodic reference resets; options under `refill:`). A hopper
model: for each simulation of the chosen split part, the model is rolled over the whole trajectory from the
scalars alone, its occupancy and transport fields are evaluated at the initial particle positions, and the
same functions that scored the DEM data compute drainage time, residual, outflow, flow regime, stripes and
residence time. Writes metrics.json, table.md (layout of the paper's Table 4), PNG figures and VTK files into
the run folder, and prints the table. (`python -m neuraldem.evaluate` is the same command.)
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from neuraldem.cli import hydra_app
from neuraldem.config import checks
from neuraldem.errors import DataError
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
    if kind == "gns":  # a particle model, not a scene's field surrogate
        raise DataError(f"{cfg.ckpt} is a GNS checkpoint: score it with python -m neuraldem.eval.gns_rollout "
                        f"--ckpt {cfg.ckpt} --out DIR")
    scene(kind, key=f"the kind of checkpoint {cfg.ckpt}").evaluate(cfg)


if __name__ == "__main__":
    main()
