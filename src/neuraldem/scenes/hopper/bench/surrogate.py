"""The trained hopper surrogate as a benchmark sees it: loaded from a checkpoint, checked against the dataset
whose questions it answers, and asked for fields over a whole trajectory (`scenes.hopper.predict`).

A question is what a practitioner asks of a simulation: occupancy, transport and residence at a set of
points, at every snapshot time from opening to the horizon. The solver answers it by simulating and then
post-processing particles; the surrogate by one model call per snapshot time.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.data.normalization import HopperNormalizer
from neuraldem.eval.checkpoints import checkpoint_dataset, checkpoint_metadata, read_checkpoint, require_kind
from neuraldem.models.registry import build_net as build_named_net
from neuraldem.models.schemas import build_net
from neuraldem.scenes.hopper.analysis.evaluation import load_hopper_checkpoint
from neuraldem.scenes.hopper.dataset.store import HopperFile
from neuraldem.scenes.hopper.surrogate.inference import ModelPredictor
from neuraldem.scenes.hopper.surrogate.predictors import TrajectoryFields, time_grid


@dataclass
class Surrogate:
    predictor: ModelPredictor
    metadata: dict
    checkpoint: Path | None
    parameters: int
    load_s: float  # wall seconds to read the checkpoint and build the model (once per session)


@dataclass
class Question:
    """Fields at `points` (Q, 3) for every time in `times`, for the simulation `record` (its scalars)."""

    record: SimRecord
    times: np.ndarray
    points: np.ndarray

    def describe(self) -> dict:
        return {"sim_id": self.record.sim_id, "n_times": len(self.times), "n_points": len(self.points),
                "horizon_s": float(self.times[-1])}


def load_surrogate(ckpt: Path, device: str = "cpu") -> Surrogate:
    """A hopper checkpoint as a predictor; a checkpoint of another kind is refused with a message."""
    require_kind(checkpoint_metadata(Path(ckpt)), "hopper", Path(ckpt), "this benchmark")
    t0 = time.perf_counter()
    module = load_hopper_checkpoint(Path(ckpt), device)
    load_s = time.perf_counter() - t0
    meta = module.metadata
    predictor = ModelPredictor(module.net, HopperNormalizer.from_dict(meta["normalizer"]),
                               list(meta["conditioning"]), chunk_size=module.chunk_size or 16384, device=device)
    return Surrogate(predictor, meta, Path(ckpt), sum(p.numel() for p in module.net.parameters()), load_s)


def surrogate_dataset(surrogate: Surrogate, dataset_dir: Path | None, datasets_dir: Path) -> tuple[Path, Manifest]:
    """The dataset the surrogate was trained on (default `datasets_dir/<data_name>`), checked to be of the
    same scene, so the surrogate and the solver answer questions about the same hopper."""
    meta = surrogate.metadata
    dataset_dir, m = checkpoint_dataset(meta, surrogate.checkpoint or Path("?"), datasets_dir, dataset_dir)
    return dataset_dir, m


def full_question(m: Manifest, dataset_dir: Path, rec: SimRecord, norm: HopperNormalizer) -> Question:
    """Every snapshot time up to the model's horizon, at every initial particle position of `rec`."""
    with HopperFile(Path(dataset_dir) / str(rec.file)) as f:
        points = f.initial_positions()
    times = time_grid(norm.horizon, float(m.scene["hopper"]["snapshot_interval"]))
    return Question(rec, times, points)


def reduced_question(q: Question, n_points: int, seed: int = 0) -> Question:
    """The same question at `n_points` of its points (a seeded random subset; all of them if fewer)."""
    if n_points >= len(q.points):
        return q
    idx = np.sort(np.random.default_rng(seed).choice(len(q.points), n_points, replace=False))
    return Question(q.record, q.times, q.points[idx])


def answer(surrogate: Surrogate, q: Question) -> TrajectoryFields:
    return surrogate.predictor.fields(q.record, q.times, q.points)


# ---- untrained surrogates of any size, for cost scaling (the cost of a forward pass does not depend on
# the weights, so sizes that were never trained can be timed)

UNIT_BOX = ([0.0, 0.0, 0.0], [1.0, 1.0, 1.0])


def net_config_of(ckpt: Path) -> dict:
    """The `net:` config a checkpoint was trained with (to build untrained copies of other sizes)."""
    c = read_checkpoint(ckpt)
    require_kind(c.metadata, "hopper", Path(ckpt), "this benchmark")
    return dict(c.hyper_parameters["net"])


def untrained_surrogate(net_cfg: dict | str, conditioning: list[str], **net_overrides: int) -> Surrogate:
    """A net of the given config (a `conf/model/` name or a `net:` dict, with overrides such as
    n_latent_tokens=64), random weights, a unit-box normaliser; for timing only."""
    torch.manual_seed(0)
    if isinstance(net_cfg, str):
        net = build_named_net(net_cfg, n_scalars=len(conditioning), **net_overrides)
    else:
        net = build_net(OmegaConf.create({**net_cfg, "n_scalars": len(conditioning), **net_overrides}))
    net.eval()
    scalars = [c for c in conditioning if c != "t"]
    norm = HopperNormalizer(list(UNIT_BOX[0]), list(UNIT_BOX[1]), horizon=1.0,
                            scalar_lo=dict.fromkeys(scalars, 0.0), scalar_hi=dict.fromkeys(scalars, 1.0))
    meta = {"kind": "hopper", "data_name": None, "conditioning": conditioning, "net_overrides": net_overrides}
    return Surrogate(ModelPredictor(net, norm, conditioning), meta, None,
                     sum(p.numel() for p in net.parameters()), 0.0)


def synthetic_question(surrogate: Surrogate, n_points: int, n_times: int, seed: int = 0) -> Question:
    """`n_points` uniform points in the surrogate's box at `n_times` times over its horizon."""
    norm = surrogate.predictor.norm
    rng = np.random.default_rng(seed)
    points = norm.positions_back(rng.uniform(0.0, 1.0, size=(n_points, 3)))
    times = np.linspace(0.0, norm.horizon, n_times)
    params = {c: 0.5 * (norm.scalar_lo[c] + norm.scalar_hi[c]) for c in surrogate.predictor.conditioning
              if c != "t"}
    return Question(SimRecord(sim_id="synthetic", index=0, params=params), times, points)
