"""Scaling of fluidized-bed states between physical units and the model's units, fitted on the training split.

Positions map the grid box to [0, 1]^3 (the frame of `MultiBranchOperator`); every channel of the
displacement, fluid velocity, solid fraction and mixing concentration is standardised with its mean and
standard deviation over the training trajectories; the inlet velocity maps its training range to [0, 1].
The statistics travel inside every checkpoint, so a model is always rolled out with the scaling it was
trained with, and they record what the model has seen (velocity range, trajectory length, grid) so that a
rollout can say when it is asked to extrapolate.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.errors import DataError
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile

FIELDS = ("displacement", "fluid_velocity", "solid_fraction", "mixing", "solids_flux")
CHANNELS = {"displacement": 3, "fluid_velocity": 3, "solid_fraction": 1, "mixing": 1, "solids_flux": 3}
STD_FLOOR = 1e-3  # a channel's std is at least this share of its field's largest channel std (no 0 division)
STEP_SCALE_FLOOR = 1e-2  # model units: a channel that never changes (the y velocity of a pseudo-2D bed)
STEP_FIELDS = ("fluid_velocity", "solid_fraction", "mixing")


@dataclass
class BedNormalizer:
    box_lo: list[float]  # grid box [m]
    box_hi: list[float]
    grid_shape: list[int]  # cells (nx, ny, nz)
    dt: float  # [s] one model step (snapshot interval)
    horizon_steps: int  # steps of the longest training trajectory (the "training horizon")
    velocity_lo: float  # [m/s] inlet velocities seen in training
    velocity_hi: float
    mean: dict[str, list[float]] = field(default_factory=dict)  # per field in FIELDS, one value per channel
    std: dict[str, list[float]] = field(default_factory=dict)
    n_particles: int = 0  # particles per trajectory (training)
    particle_volume: float = 0.0  # [m^3] mean particle volume
    solid_fraction_max: float = 0.0  # largest solid fraction in the training data
    # RMS of the change over one model step per channel, physical units (fluid_velocity, solid_fraction, mixing):
    # the scale of what a residual model predicts (`step_scale`); empty in normalisers fitted before it existed
    step_rms: dict[str, list[float]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> BedNormalizer:
        return cls(**d)

    # ---- positions
    def positions(self, x: np.ndarray) -> np.ndarray:
        lo, hi = np.asarray(self.box_lo), np.asarray(self.box_hi)
        return (np.asarray(x) - lo) / (hi - lo)

    def positions_back(self, u: np.ndarray) -> np.ndarray:
        lo, hi = np.asarray(self.box_lo), np.asarray(self.box_hi)
        return lo + np.asarray(u) * (hi - lo)

    # ---- fields: the last axis holds the channels (a scalar field has none)
    def _stats(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        if name not in FIELDS:
            raise DataError(f"no normalisation for field {name!r}; have {list(FIELDS)}")
        if name not in self.mean:
            raise DataError(f"this normalisation has no statistics for {name!r} (fitted without it): train with "
                            f"data.datamodule.solids_flux=true to use the solids flux")
        return np.asarray(self.mean[name]), np.asarray(self.std[name])

    def field(self, name: str, x: np.ndarray) -> np.ndarray:
        mean, std = self._stats(name)
        x = np.asarray(x)
        return ((x[..., None] if CHANNELS[name] == 1 else x) - mean) / std

    def field_back(self, name: str, u: np.ndarray) -> np.ndarray:
        """Inverse of `field`: (..., channels) model units -> physical (scalar fields lose the last axis)."""
        mean, std = self._stats(name)
        x = np.asarray(u) * std + mean
        return x[..., 0] if CHANNELS[name] == 1 else x

    def step_scale(self, name: str) -> np.ndarray:
        """Per-channel RMS of one step's change in model units (>= STEP_SCALE_FLOOR): a residual model predicts
        (next - current) / step_scale, so every channel's change is of order one in its loss, the solid fraction's
        small per-step change as much as the fluid velocity's large one."""
        if name not in self.step_rms:
            raise DataError(f"this normalisation has no one-step statistics for {name!r} (fitted by an older "
                            "neuraldem): retrain, or train without model.residual")
        return np.maximum(np.asarray(self.step_rms[name]) / np.asarray(self.std[name]), STEP_SCALE_FLOOR)

    # ---- conditioning
    def velocity(self, v: float) -> float:
        span = self.velocity_hi - self.velocity_lo
        return (float(v) - self.velocity_lo) / span if span > 0 else 0.5

    def in_trained_range(self, v: float, rtol: float = 1e-6) -> bool:
        tol = rtol * max(abs(self.velocity_lo), abs(self.velocity_hi), 1.0)
        return self.velocity_lo - tol <= float(v) <= self.velocity_hi + tol

    # ---- fitting
    @classmethod
    def fit(cls, paths: Sequence[Path], solids_flux: bool = False) -> BedNormalizer:
        """Statistics of the given (training) trajectories, read one file at a time (`solids_flux`: also of the
        kernel solids flux, computed from the particles: a few seconds per 300-step file)."""
        if not paths:
            raise DataError("no training trajectories to fit the normalisation on")
        acc = {name: _Moments(CHANNELS[name]) for name in FIELDS if solids_flux or name != "solids_flux"}
        steps = {name: _Moments(CHANNELS[name]) for name in STEP_FIELDS}  # of the one-step changes
        grids, velocities, horizons, dts, counts, volumes, alpha_max = set(), [], [], [], [], [], 0.0
        for path in paths:
            with BedFile(path) as f:  # validates the file
                grids.add((f.grid.lo, f.grid.hi, f.grid.shape))
                velocities.append(f.inlet_velocity)
                horizons.append(f.n_snapshots - 1)
                dts.append(f.dt)
                counts.append(f.n_particles)
                volumes.append(float(np.mean(f.particle_volumes)))
                acc["displacement"].add(f.displacement().reshape(-1, 3))
                alpha = f.solid_fraction()
                alpha_max = max(alpha_max, float(alpha.max()))
                if solids_flux:
                    acc["solids_flux"].add(f.solids_flux()[1:].reshape(-1, 3))  # snapshot 0 has no last step
                for name, values in (("fluid_velocity", f.fluid_velocity()), ("solid_fraction", alpha),
                                     ("mixing", f.mixing())):
                    acc[name].add(values.reshape(-1, CHANNELS[name]))
                    steps[name].add(np.diff(values, axis=0).reshape(-1, CHANNELS[name]))
        if len(grids) != 1:
            raise DataError(f"training trajectories {[str(p) for p in paths]} use {len(grids)} different grids; "
                            "a dataset must have one grid (regenerate or import them onto the same grid)")
        if not np.all(np.isfinite(velocities)):
            raise DataError("a training trajectory has no params.inlet_velocity attribute (imported without "
                            "--inlet-velocity?)")
        if max(dts) - min(dts) > 1e-9 * max(dts) or max(horizons) < 1:
            raise DataError(f"training trajectories need >= 2 snapshots at one interval (found {sorted(set(dts))} s)")
        (lo, hi, shape), = grids
        mean, std = {}, {}
        for name, m in acc.items():
            mu, sd = m.result()
            sd = np.maximum(sd, max(STD_FLOOR * float(sd.max()), 1e-12))
            mean[name], std[name] = mu.tolist(), sd.tolist()
        return cls(box_lo=list(lo), box_hi=list(hi), grid_shape=list(shape), dt=float(dts[0]),
                   horizon_steps=int(max(horizons)), velocity_lo=float(min(velocities)),
                   velocity_hi=float(max(velocities)), mean=mean, std=std, n_particles=int(max(counts)),
                   particle_volume=float(np.mean(volumes)), solid_fraction_max=alpha_max,
                   step_rms={name: m.rms().tolist() for name, m in steps.items()})


class _Moments:
    """Streaming per-channel mean and standard deviation (NaN rows, e.g. lost particles, are skipped)."""

    def __init__(self, channels: int):
        self.n = 0
        self.s = np.zeros(channels)
        self.ss = np.zeros(channels)

    def add(self, x: np.ndarray) -> None:
        x = x[np.isfinite(x).all(axis=1)]
        self.n += len(x)
        self.s += x.sum(axis=0)
        self.ss += np.square(x).sum(axis=0)

    def rms(self) -> np.ndarray:
        return np.sqrt(self.ss / max(self.n, 1))

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        mean = self.s / max(self.n, 1)
        var = np.maximum(self.ss / max(self.n, 1) - mean**2, 0.0)
        return mean, np.sqrt(var)


def grid_input(norm: BedNormalizer, fluid_velocity: np.ndarray, solid_fraction: np.ndarray,
               solids_flux: np.ndarray | None = None) -> np.ndarray:
    """Fluid-branch input (4 or 7, nx, ny, nz): normalised fluid velocity (3 channels) + solid fraction
    (+ solids flux, 3 channels, when given)."""
    parts = [norm.field("fluid_velocity", fluid_velocity), norm.field("solid_fraction", solid_fraction)]
    if solids_flux is not None:
        parts.append(norm.field("solids_flux", solids_flux))
    return np.moveaxis(np.concatenate(parts, axis=-1), -1, 0)


def mixing_input(norm: BedNormalizer, mixing: np.ndarray) -> np.ndarray:
    """Off-branch input (1, nx, ny, nz): normalised mixing concentration."""
    return np.moveaxis(norm.field("mixing", mixing), -1, 0)
