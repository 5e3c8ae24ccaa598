"""What-if answers for a hopper nobody has simulated: the numbers from the scalar GP, the fields from the field
model, and (to check either) LIGGGHTS itself on the same parameters.

- GP: drainage t95, the 1 % drainage time, residual, outflow and the mass-flow index with 95 % intervals, in
  milliseconds (one `predict` call on the scene parameters).
- Field model: occupancy, transport and residence over the whole discharge at query points that fill the
  hopper. Without a solver run there is no initial packing, so the points are a lattice at the packing's
  particle spacing inside the hopper of this cone angle, kept where the model says material is at t = 0; the
  numbers are then read off the fields with the same functions as for DEM (`metrics.hopper_summary`).
- LIGGGHTS: `run_hopper` + `datagen.trajectory_metrics`, the path every dataset run takes.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from neuraldem.errors import DataError
from neuraldem.scenes.hopper.analysis.metrics import HopperMetricSettings, flow_regime
from neuraldem.scenes.hopper.solver import HopperGeometry, HopperScene

if TYPE_CHECKING:
    from neuraldem.scenes.hopper.surrogate.predictors import TrajectoryFields

PACKING_FRACTION = 0.6  # random close packing of the settled fill: sets the lattice spacing
QUANTITIES = {  # answer key -> (label, unit, scale to the unit)
    "drainage_t95": ("drainage t95", "s", 1.0),
    "drainage_time": ("drainage time (1 % rule)", "s", 1.0),
    "residual_fraction": ("residual", "%", 100.0),
    "outflow_rate": ("outflow", "%/s", 100.0),
    "mass_flow_index": ("mass-flow index", "", 1.0),
}


@dataclass(frozen=True)
class QueryBudget:
    """How many queries the field model's numbers cost: a share of the lattice points (a fixed, seeded subsample of
    the material found at t = 0, so the points keep the fill's distribution) and every n-th time of the snapshot
    grid. The numbers are fractions and times read off a discharge curve, so far fewer queries than one per
    particle and snapshot answer them nearly as well (`neuraldem bench query_budget`,
    results/hopper/speed/query_budget.md; a coarser lattice instead biased the outflow by a few percent, and an
    unstratified share added up to 2 percentage points to its error on the validation runs)."""

    points: float = 1.0
    time_stride: int = 1

    def __post_init__(self) -> None:
        from neuraldem.config import checks

        checks.number("query_points", self.points, lo=MIN_POINT_SHARE, hi=1.0)
        checks.positive_int("time_stride", self.time_stride)
        if self.time_stride > MAX_TIME_STRIDE:
            raise DataError(f"time_stride={self.time_stride} is invalid: at most {MAX_TIME_STRIDE} (every "
                            f"{MAX_TIME_STRIDE * 0.05:g} s of the 0.05-s grid; the drainage time needs finer)")

    def as_dict(self) -> dict[str, float]:
        return {"query_points": self.points, "time_stride": self.time_stride}

    def subsample(self, points: np.ndarray) -> np.ndarray:
        """The budget's share of `points`, stratified by height and radius (the fill drains in that order, so
        every stratum keeps its share of the count): a seeded subsample in the lattice's order."""
        if self.points >= 1.0:
            return points
        keep = max(MIN_POINTS, int(round(self.points * len(points))))
        if keep >= len(points):
            return points
        rng = np.random.default_rng(0)
        z, r = points[:, 2], np.hypot(points[:, 0], points[:, 1])
        strata = np.digitize(z, np.quantile(z, np.linspace(0, 1, Z_STRATA + 1)[1:-1])) * R_STRATA + \
            np.digitize(r, np.quantile(r, np.linspace(0, 1, R_STRATA + 1)[1:-1]))
        chosen = []
        for s in np.unique(strata):
            members = np.flatnonzero(strata == s)
            n = max(1, int(round(len(members) * keep / len(points))))
            chosen.append(rng.choice(members, size=min(n, len(members)), replace=False))
        return points[np.sort(np.concatenate(chosen))]


MIN_POINT_SHARE = 0.01
MIN_POINTS = 64  # fewer material points cannot count eight height layers
Z_STRATA, R_STRATA = 16, 4  # strata of the subsample: heights (the eight layers, halved) and radii
MAX_TIME_STRIDE = 20
# the budget of `neuraldem predict`'s field numbers: the cheapest whose errors against LIGGGHTS stay within 10 %
# of the full budget's on the validation runs (results/hopper/speed/query_budget.md)
ANSWER_BUDGET = QueryBudget(0.0625, 4)


def lattice_points(scene: HopperScene, alpha: float, box_lo: np.ndarray, box_hi: np.ndarray) -> np.ndarray:
    """A cubic lattice at the packing's particle spacing: centres a radius inside the cylinder wall, above the
    cone of angle `alpha` and the closed outlet, below the top of the box the model knows."""
    d = scene.material.diameter
    geom = HopperGeometry.for_angle(scene, alpha)
    spacing = d * (math.pi / 6 / PACKING_FRACTION) ** (1 / 3)
    r_max = geom.radius - d / 2
    xy = np.arange(-r_max, r_max + 1e-12, spacing)
    z = np.arange(d / 2, min(geom.wall_height, float(box_hi[2])) - d / 2 + 1e-12, spacing)
    x, y, zz = (a.ravel() for a in np.meshgrid(xy, xy, z, indexing="ij"))
    r = np.hypot(x, y)
    cone = np.maximum(r - geom.outlet_radius, 0.0) * math.tan(math.radians(alpha))
    keep = (r <= r_max) & (zz >= cone + d / 2)
    points = np.stack([x[keep], y[keep], zz[keep]], axis=1)
    inside = np.all((points >= box_lo) & (points <= box_hi), axis=1)
    return points[inside]


@dataclass
class FieldAnswer:
    points: np.ndarray  # (Q, 3) query points occupied at t = 0
    fields: TrajectoryFields
    summary: dict[str, float]
    stripes: np.ndarray  # (T, layers)
    seconds: float
    extrapolation: dict[str, list[float]]


def predictor_for(net: Any, meta: dict[str, Any]) -> Any:
    """The field predictor of a net: an exported one (`models.onnx_runtime.OnnxNet`) is answered without torch."""
    from neuraldem.data.normalization import HopperNormalizer

    norm = HopperNormalizer.from_dict(meta["normalizer"])
    if hasattr(net, "session"):
        from neuraldem.scenes.hopper.surrogate.predictors import OnnxPredictor

        return OnnxPredictor(net, norm, list(meta["conditioning"]), times_per_call=16)
    from neuraldem.scenes.hopper.surrogate.inference import ModelPredictor  # torch: only for a torch net

    return ModelPredictor(net, norm, list(meta["conditioning"]), times_per_call=16)


def field_answer(net: Any, meta: dict[str, Any], params: dict[str, float], settings: HopperMetricSettings,
                 threshold: float = 0.5, time_stride: int = 1, budget: QueryBudget | None = None) -> FieldAnswer:
    """The field model's answer for scene parameters `params` (those of its conditioning besides t), from the
    queries of `budget` (default: every lattice point, every `time_stride`-th snapshot)."""
    from neuraldem.data.manifest import SimRecord
    from neuraldem.scenes.hopper.analysis.metrics import metric_times
    from neuraldem.scenes.hopper.analysis.scoring import summarise

    t0 = time.perf_counter()
    budget = budget or QueryBudget(1.0, time_stride)
    predictor = predictor_for(net, meta)
    norm = predictor.norm
    hop = meta["scene"]["hopper"]
    scene = HopperScene.from_config(hop, "model scene")
    rec = SimRecord("what-if", 0, dict(params))
    lattice = lattice_points(scene, float(params["alpha"]), np.asarray(norm.box_lo), np.asarray(norm.box_hi))
    start = predictor.fields(rec, np.array([0.0]), lattice).occupancy[0]
    points = budget.subsample(lattice[start >= threshold])
    if len(points) == 0:
        raise DataError(f"the field model sees no material at t = 0 for {params}",
                        "ask within the trained ranges, or use the GP answer")
    times = metric_times(norm.horizon, float(hop["snapshot_interval"]))[::budget.time_stride]
    fields = predictor.fields(rec, times, points)
    summary, stripes = summarise(fields, points[:, 2], settings)
    return FieldAnswer(points, fields, summary, stripes, time.perf_counter() - t0, predictor.extrapolation(rec))


@dataclass
class FieldFrames:
    points: np.ndarray  # (Q, 3) the whole lattice occupied at t = 0
    fields: TrajectoryFields
    stripes: np.ndarray  # (T, layers)


def field_frames(net: Any, meta: dict[str, Any], params: dict[str, float], settings: HopperMetricSettings,
                 time_stride: int = 2, threshold: float = 0.5) -> FieldFrames:
    """The fields of the whole lattice (one query per particle spacing) at every `time_stride`-th time, answered
    one frame per call: what pictures and ParaView files show, after the numbers."""
    from neuraldem.data.manifest import SimRecord
    from neuraldem.scenes.hopper.analysis.metrics import layer_edges, layer_stripes, metric_times

    predictor = predictor_for(net, meta)
    predictor.times_per_call = 1
    norm = predictor.norm
    hop = meta["scene"]["hopper"]
    rec = SimRecord("what-if", 0, dict(params))
    lattice = lattice_points(HopperScene.from_config(hop, "model scene"), float(params["alpha"]),
                             np.asarray(norm.box_lo), np.asarray(norm.box_hi))
    points = lattice[predictor.fields(rec, np.array([0.0]), lattice).occupancy[0] >= threshold]
    fields = predictor.fields(rec, metric_times(norm.horizon, float(hop["snapshot_interval"]))[::time_stride],
                              points)
    stripes = layer_stripes(fields.occupancy, fields.transport[..., 2], layer_edges(points[:, 2], settings.n_layers))
    return FieldFrames(points, fields, stripes)


@dataclass
class SolverAnswer:
    status: str
    reason: str
    metrics: dict[str, float]
    seconds: float
    stripes: np.ndarray | None
    times: np.ndarray | None


def liggghts_answer(scene: HopperScene, params: dict[str, float], workdir: Path,
                    settings: HopperMetricSettings) -> SolverAnswer:
    """LIGGGHTS on the same parameters, scored like every dataset run (fields at the initial positions)."""
    from neuraldem.scenes.hopper.analysis.metrics import layer_edges, layer_stripes
    from neuraldem.scenes.hopper.dataset.datagen import metric_fields, trajectory_metrics
    from neuraldem.scenes.hopper.solver import run_hopper

    t0 = time.perf_counter()
    result = run_hopper(scene, params["alpha"], params["mu_s"], params["mu_r"], workdir, index=0)
    seconds = time.perf_counter() - t0
    traj = result.trajectory
    if traj is None:
        return SolverAnswer(result.status, result.reason, {}, seconds, None, None)
    fields = metric_fields(traj, scene.material.diameter, settings, scene.max_time)  # once, for both uses
    metrics = trajectory_metrics(traj, scene.material.diameter, settings, scene.max_time, fields=fields)
    stripes = layer_stripes(fields.occupancy.astype(np.float64), fields.transport[..., 2],
                            layer_edges(fields.points[:, 2], settings.n_layers))
    return SolverAnswer(result.status, result.reason, metrics, seconds, stripes, fields.times)


def regime(index: float, settings: HopperMetricSettings) -> str:
    return flow_regime(index, settings.mass_flow_threshold) if np.isfinite(index) else "-"
