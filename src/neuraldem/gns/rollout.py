"""Rollout of the particle-based baseline (GNS) with stability checks, and its scene metrics.

From the first H + 1 snapshots of a stored run (H = the model's history), every step predicts the
accelerations of the particles present and integrates them with semi-implicit Euler:
v_{t+1} = v_t + a_t dt, x_{t+1} = x_t + v_{t+1} dt (v_t = (x_t - x_{t-1}) / dt, the finite difference the
model was trained on, so exact accelerations reproduce the data exactly). Hopper particles that fall below
the sink plane have left, as in the data (NaN from then on).

Every new state is checked (`check_state`), in this order, and the first problem stops the rollout with its
step and reason (the states before it are kept): the particle count changed (particles neither present nor
exited: the mass is not conserved), NaN/inf positions, a particle outside the domain box (by more than
`box_tolerance_d` diameters), overlaps (pairs closer than `overlap_fraction` of their mean diameter; more than
`max_overlaps` of them).

Metrics with the ground truth's functions: hopper, the particle count above the outlet plane (z >= 0) per
snapshot through `scenes.hopper.metrics` (drainage time, residual, outflow rate, mass-flow index from the
initial height layers), for the rollout and the stored run alike; fluidized bed, the kernel solid fraction and
mixing fields of the predicted particles (`scenes.fluidized_bed.fields`, the stored files' own kernels) scored with
`scenes.fluidized_bed.evaluation.compare` against the stored fields (the GNS has no air: fluid statistics are NaN).

`neuraldem report gns-rollout ckpt=CKPT [sim=SIM_ID] [steps=N] out=DIR` writes
gns_rollout.json (summary, metrics) and gns_rollout.h5 (times, positions).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import torch
from scipy.spatial import cKDTree

from neuraldem.cli import command_parser
from neuraldem.config import checks
from neuraldem.data.manifest import Manifest
from neuraldem.data.schema import atomic_write_h5, atomic_write_json
from neuraldem.errors import DataError, NeuraldemError
from neuraldem.eval.checkpoints import checkpoint_dataset, read_checkpoint
from neuraldem.gns.datamodule import GnsNormalizer, ParticleRun, graph_inputs
from neuraldem.gns.module import GnsModule
from neuraldem.paths import data_dir
from neuraldem.scenes.fluidized_bed.dataset.fields import mixing_concentration, particle_volumes, solid_fraction
from neuraldem.scenes.hopper.analysis import metrics as hm

# (step, one graph's inputs) -> accelerations [m/s^2] of the particles present; tests inject faulty ones
Accelerator = Callable[[int, dict[str, torch.Tensor]], np.ndarray]


@dataclass
class StabilityLimits:
    box_tolerance_d: float = 0.5  # a centre this many diameters outside the box has left the domain
    overlap_fraction: float = 0.5  # pairs closer than this share of their mean diameter overlap
    max_overlaps: int = 0  # more overlapping pairs than this is a failure

    def __post_init__(self) -> None:
        checks.number("box_tolerance_d", self.box_tolerance_d, lo=0.0)
        checks.number("overlap_fraction", self.overlap_fraction, lo=0.0, hi=1.0)
        checks.positive_int("max_overlaps", self.max_overlaps, allow_zero=True)


def count_overlaps(positions: np.ndarray, diameters: np.ndarray, fraction: float) -> int:
    """Pairs of centres closer than `fraction` x their mean diameter."""
    if len(positions) < 2 or fraction <= 0:
        return 0
    pairs = cKDTree(positions).query_pairs(fraction * float(np.max(diameters)), output_type="ndarray")
    if not len(pairs):
        return 0
    i, j = pairs[:, 0], pairs[:, 1]
    dist = np.linalg.norm(positions[i] - positions[j], axis=1)
    return int(np.sum(dist < fraction * 0.5 * (diameters[i] + diameters[j])))


def check_state(positions: np.ndarray, diameters: np.ndarray, n_exited: int, n_initial: int, box_lo: np.ndarray,
                box_hi: np.ndarray, limits: StabilityLimits) -> tuple[str | None, int]:
    """Why a state (centres (M, 3) of the particles present, their diameters) is unphysical (None if it is
    not), and its overlap count (-1 where not counted)."""
    if len(positions) + n_exited != n_initial:
        return ((f"particle count changed: {len(positions)} present + {n_exited} exited != {n_initial} at the start "
                "(mass not conserved)"), -1)
    bad = ~np.isfinite(positions).all(axis=1)
    if bad.any():
        return f"NaN/inf positions of {int(bad.sum())} particle(s)", -1
    tol = limits.box_tolerance_d * diameters[:, None]
    out = (positions < np.asarray(box_lo) - tol) | (positions > np.asarray(box_hi) + tol)
    if out.any():
        k = int(np.flatnonzero(out.any(axis=1))[0])
        return ((f"{int(out.any(axis=1).sum())} particle(s) left the domain box (e.g. at "
                f"{np.round(positions[k], 4).tolist()} m, box {np.round(box_lo, 4).tolist()} .. "
                f"{np.round(box_hi, 4).tolist()} m)"), -1)
    n = count_overlaps(positions, diameters, limits.overlap_fraction)
    if n > limits.max_overlaps:
        return ((f"{n} overlapping pair(s) (centres closer than {limits.overlap_fraction:g} diameters; limit "
                f"{limits.max_overlaps})"), n)
    return None, n


@dataclass
class GnsRollout:
    """Positions (T, N, 3) [m] of every particle of the run (NaN = absent or exited); the first H + 1 are the
    given snapshots, step k is index H + k. `failed_at`: the step whose state failed a check (not kept)."""

    times: np.ndarray
    positions: np.ndarray
    history: int
    steps_requested: int
    failed_at: int | None = None
    failure: str = ""
    overlaps: list[int] = field(default_factory=list)  # per step done
    solid_fraction: np.ndarray | None = None  # fluidized bed: (steps done + 1, nx, ny, nz) from step 0 on

    @property
    def steps_done(self) -> int:
        return len(self.times) - self.history - 1

    # the names `scenes.fluidized_bed.bench.stability.assess` reads
    @property
    def diverged_at(self) -> int | None:
        return self.failed_at

    @property
    def divergence(self) -> str:
        return self.failure

    def summary(self) -> dict[str, Any]:
        return {"steps_requested": self.steps_requested, "steps_done": self.steps_done,
                "failed": self.failed_at is not None, "steps_to_failure": self.failed_at, "failure": self.failure,
                "steps_stable": self.failed_at if self.failed_at is not None else self.steps_done,
                "max_overlaps": max(self.overlaps, default=0)}


def rollout(accelerate: Accelerator, run: ParticleRun, norm: GnsNormalizer, scalars: np.ndarray, steps: int,
            start: int = 0, limits: StabilityLimits | None = None) -> GnsRollout:
    """Integrate `accelerate` for `steps` steps from snapshots start .. start + H of `run` (module docstring)."""
    checks.positive_int("steps", steps)
    h, dt = norm.history, norm.dt
    if not 0 <= start <= run.n_snapshots - h - 1:
        raise DataError(f"{run.path}: a rollout from snapshot {start} needs snapshots {start} .. {start + h}; the "
                        f"run has {run.n_snapshots}")
    if abs(run.dt - dt) > 1e-9 * dt:
        raise DataError(f"{run.path}: snapshot interval {run.dt} s differs from the model's step {dt} s")
    limits = limits or StabilityLimits()
    hist = run.positions(slice(start, start + h + 1)).copy()  # (H + 1, N, 3)
    tracked = np.isfinite(hist[-1]).all(axis=1)
    hist[:, ~tracked] = np.nan
    exited = np.zeros(len(tracked), dtype=bool)
    n_initial = int(tracked.sum())
    states, overlaps = list(hist), []
    failed_at, failure = None, ""
    for s in range(1, steps + 1):
        alive = tracked & ~exited
        present = np.flatnonzero(alive)
        a = (np.asarray(accelerate(s, graph_inputs(norm, run, hist[:, alive], scalars)), dtype=np.float64)
             if len(present) else np.zeros((0, 3)))  # an empty hopper stays empty
        if a.shape != (len(present), 3):  # a predictor that lost or invented particles
            failed_at, failure = s, (f"particle count changed: {len(a)} accelerations for {len(present)} particles "
                                     "(mass not conserved)")
            break
        new = np.full_like(hist[-1], np.nan)
        v = (hist[-1, alive] - hist[-2, alive]) / dt + a * dt
        new[alive] = hist[-1, alive] + v * dt
        if run.exit_z is not None:
            with np.errstate(invalid="ignore"):
                gone = alive & (new[:, 2] < run.exit_z)
            exited |= gone
            new[gone] = np.nan
        present = np.flatnonzero(tracked & ~exited)
        problem, n_overlap = check_state(new[present], run.diameters[present], int(exited.sum()), n_initial,
                                         run.box_lo, run.box_hi, limits)
        if problem is not None:
            failed_at, failure = s, problem
            break
        overlaps.append(n_overlap)
        states.append(new)
        hist = np.concatenate([hist[1:], new[None]])
    times = run.times[start] + dt * np.arange(len(states))
    return GnsRollout(times=times, positions=np.stack(states), history=h, steps_requested=steps,
                      failed_at=failed_at, failure=failure, overlaps=overlaps)


def model_accelerator(module: GnsModule) -> Accelerator:
    module.eval()
    return lambda step, inputs: module.acceleration(inputs)


# ---- metrics with the ground truth's functions
def hopper_particle_metrics(times: np.ndarray, positions: np.ndarray,
                            settings: hm.HopperMetricSettings = hm.HopperMetricSettings()) -> dict[str, float]:  # noqa: B008 frozen dataclass, immutable
    """`scenes.hopper.metrics.hopper_summary` with the particles as the points: occupied = present above the outlet
    plane (z >= 0), material = each particle's initial height."""
    with np.errstate(invalid="ignore"):
        occupied = np.isfinite(positions[..., 2]) & (positions[..., 2] >= 0.0)
    z0 = positions[0, :, 2]
    keep = np.isfinite(z0)
    transport_z = np.broadcast_to(z0[keep], occupied[:, keep].shape)
    return hm.hopper_summary(times, occupied[:, keep], transport_z, z0[keep], settings)


def fb_particle_fields(run: ParticleRun, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kernel solid fraction and mixing (T, nx, ny, nz) of particle positions (T, N, 3), with the stored file's
    kernels, grid and labels (as datagen computed the stored fields)."""
    f = run.f
    alpha, mix = [], []
    for pos in positions:
        a = solid_fraction(pos, run.diameters, f.grid, f.kernel_sigma)
        alpha.append(a)
        mix.append(mixing_concentration(pos, run.diameters, run.labels, f.grid, f.mixing_sigma, f.prior,
                                        f.group_b_share, a if f.mixing_sigma == f.kernel_sigma else None))
    return np.stack(alpha), np.stack(mix)


def score(r: GnsRollout, run: ParticleRun, manifest: Manifest) -> dict[str, Any]:
    """The rollout's scene metrics next to the stored run's (over the steps both have, from step 0)."""
    h = r.history
    n = min(len(r.times), run.n_snapshots)
    truth = run.positions(slice(0, n))
    if run.kind == "hopper":
        settings = hm.HopperMetricSettings.from_config(manifest.metric_settings or {})
        pred_m = hopper_particle_metrics(r.times, r.positions, settings)
        truth_m = hopper_particle_metrics(run.times[:n], truth, settings)
        return {"pred": pred_m, "truth": truth_m,
                "abs_error": {k: abs(pred_m[k] - truth_m[k]) for k in pred_m}}
    from neuraldem.scenes.fluidized_bed.analysis.evaluation import FieldSeries, compare
    from neuraldem.scenes.fluidized_bed.dataset.report import metric_settings

    f = run.f
    alpha, mix = fb_particle_fields(run, r.positions[h:])
    r.solid_fraction = alpha
    vols = particle_volumes(run.diameters)
    present = np.isfinite(r.positions[h]).all(axis=1)
    pred = FieldSeries(r.times[h:], alpha, np.full((*alpha.shape, 3), np.nan), mix, f.grid,
                       float(vols.mean()), float(vols[present].sum()))
    truth_s = FieldSeries(f.times[h:], f.solid_fraction()[h:], f.fluid_velocity()[h:], f.mixing()[h:], f.grid,
                          float(vols.mean()), float(vols[present].sum()))
    return compare(pred, truth_s, metric_settings(manifest))


# ---- checkpoints and files
def load_gns_checkpoint(path: Path, device: str = "cpu") -> GnsModule:
    """A trained GNS; a checkpoint of another kind, or one trained from an export, is refused with a message."""
    module = read_checkpoint(path).module("gns", device, "a GNS rollout")
    export = module.metadata.get("export")
    if export:
        raise DataError(f"{path} is a GNS trained from the export {export['dir']}, which sees the scene's walls "
                        "only as its box: rollouts replay stored runs with the scene's walls",
                        "roll out a GNS trained on the dataset itself (experiment=gns_hopper or gns_fb)")
    return module


def run_gns_rollout(ckpt: Path, out_dir: Path | None = None, sim: str | None = None, steps: int | None = None,
                    dataset_dir: Path | None = None, limits: StabilityLimits | None = None,
                    accelerate: Accelerator | None = None) -> dict[str, Any]:
    """Roll a GNS checkpoint out on run `sim` (default: the first test run of its split) for `steps` (default:
    the whole stored run), score it; write gns_rollout.json and .h5 into `out_dir` if given."""
    if steps is not None:
        checks.positive_int("steps", steps)
    module = load_gns_checkpoint(Path(ckpt))
    meta, norm = module.metadata, module.norm
    dataset_dir, m = checkpoint_dataset(meta, Path(ckpt), data_dir() / "datasets", dataset_dir)
    if sim is None:
        test = m.split_ids(meta["split"], "test") or m.split_ids(meta["split"], "val")
        if not test:
            raise DataError(f"split {meta['split']!r} of {dataset_dir} has no test or validation run: pass sim=")
        sim = test[0]
    rec = m.record(sim)
    if not rec.usable:
        raise DataError(f"simulation {sim} of {dataset_dir} is not finished (status {rec.status})")
    with ParticleRun(dataset_dir / str(rec.file), meta["scene_kind"], m.scene) as run:
        steps = steps or run.n_snapshots - norm.history - 1
        r = rollout(accelerate or model_accelerator(module), run, norm, norm.scalars(rec.conditioning()), steps,
                    limits=limits)
        metrics = score(r, run, m)
    result = {"checkpoint": str(Path(ckpt).resolve()), "data_name": meta["data_name"], "sim_id": sim,
              "scene_kind": meta["scene_kind"], "conditioning": rec.conditioning(), **r.summary(),
              "metrics": _jsonable(metrics)}
    if out_dir is not None:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out_dir / "gns_rollout.json", result)

        def fill(f: h5py.File) -> None:
            f.attrs.update(kind="gns_rollout", sim_id=sim, failure=r.failure,
                           failed_at=-1 if r.failed_at is None else r.failed_at)
            f.create_dataset("time", data=r.times)
            f.create_dataset("position", data=r.positions.astype(np.float32), compression="gzip")

        atomic_write_h5(out_dir / "gns_rollout.h5", fill)
    return result


def _jsonable(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    return v


def main(argv: list[str] | None = None) -> int:
    p = command_parser("neuraldem.gns.rollout", __doc__, summary=True)
    p.add_argument("--ckpt", type=Path, required=True, help="a GNS checkpoint (experiment=gns_hopper / gns_fb)")
    p.add_argument("--sim", default=None, help="simulation id (default: the first test run of the split)")
    p.add_argument("--steps", type=int, default=None, help="steps (default: the stored run's length)")
    p.add_argument("--dataset", type=Path, default=None, help="dataset dir (default: <data dir>/datasets/<name>)")
    p.add_argument("--out", type=Path, required=True, help="folder for gns_rollout.json and gns_rollout.h5")
    a = p.parse_args(argv)
    try:
        result = run_gns_rollout(a.ckpt, a.out, a.sim, a.steps, a.dataset)
    except NeuraldemError as err:
        print(f"neuraldem: error: {err}", file=sys.stderr)
        return 2
    state = f"failed at step {result['steps_to_failure']}: {result['failure']}" if result["failed"] else "stable"
    print(f"{result['sim_id']}: {result['steps_done']} of {result['steps_requested']} steps, {state}; wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
