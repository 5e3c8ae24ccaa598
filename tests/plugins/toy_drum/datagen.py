"""The toy drum's datagen pipeline: one JSON file per run, written from the synthetic stand-in."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.data.schema import sha256
from neuraldem.datagen.driver import DataConfigPipeline
from neuraldem.datagen.sampling import latin_hypercube
from toy_drum import PARAMETERS
from toy_drum.solver import dynamic_repose_deg


@dataclass
class ToyDrumPipeline(DataConfigPipeline):
    kind: str = "toy_drum"

    def __post_init__(self) -> None:
        super().__post_init__()
        self.ranges = {k: tuple(v) for k, v in self.cfg.parameters.ranges.items()}
        for k, v in self.ranges.items():
            PARAMETERS.check_range(f"data.parameters.ranges.{k}", v)

    def scene_record(self) -> dict[str, Any]:
        return {"drum": {"radius": float(self.cfg.scene.radius)}}

    def solver_record(self) -> dict[str, str]:
        return {"name": "synthetic stand-in (closed form, not a solver)", "version": "1"}

    def parameter_record(self) -> dict[str, Any]:
        return {"ranges": {k: list(v) for k, v in self.ranges.items()}, "seed": int(self.cfg.parameters.seed)}

    def new_parameters(self, n: int, batch: int) -> list[dict[str, float]]:
        return latin_hypercube(self.ranges, n, int(self.cfg.parameters.seed), batch)

    def prepare(self, manifest: Manifest) -> None:
        pass

    def incomplete(self, record: SimRecord) -> bool:
        return False

    def run_order(self, todo: list[SimRecord], manifest: Manifest) -> list[SimRecord]:
        return todo

    def run(self, record: SimRecord) -> SimRecord:
        rel = f"sims/{record.sim_id}.json"
        (self.dataset_dir / "sims").mkdir(parents=True, exist_ok=True)
        repose = dynamic_repose_deg(record.params["speed"], record.params["friction"])
        (self.dataset_dir / rel).write_text(json.dumps({"dynamic_repose_deg": repose}))
        record.file, record.sha256 = rel, sha256(self.dataset_dir / rel)
        record.metrics = {"dynamic_repose_deg": repose}
        record.status = "ok"
        return record

    def splits(self, manifest: Manifest) -> dict[str, dict[str, list[str]]]:
        ids = [r.sim_id for r in manifest.usable()]
        return {"random": {"train": ids[:-2], "val": ids[-2:-1], "test": ids[-1:]}}
