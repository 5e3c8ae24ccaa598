"""The fluidized-bed scene of OpenFOAM's DPMFoam (CFD-DEM, soft-sphere collisions, four-way coupled).

Scene: a box of width x thickness x height (x, y, z; gravity -z) meshed by blockMesh into a regular grid;
air enters uniformly through the bottom (`interstitialInletVelocity`: the superficial inlet velocity U0
divided by the local fluid fraction) and leaves through a fixed-pressure top; side walls are no-slip,
front/back symmetry planes (pseudo-2D) or no-slip walls (3D). Particles: monodisperse spheres,
`pairSpringSliderDashpot` contacts resolved in `collision_resolution_steps` substeps, drag from the
`ErgunWenYu` correlation, gravity. They start at rest in a loose random packing at the bottom
(`random_packing`, a different packing per seed), fall, and are fluidized; the first `spinup_time` seconds
are simulated but not stored, so stored t = 0 is a fluidized bed.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from neuraldem.config import checks
from neuraldem.errors import ConfigError
from neuraldem.sim.foam_reader import BoxGrid

DRAG_MODELS = ("ErgunWenYu", "WenYu", "PlessisMasliyah")
FRONT_BACK = ("symmetry", "wall")
GRAVITY = 9.81


@dataclass(frozen=True)
class BedScene:
    """Everything about a fluidized-bed run except the inlet velocity and the packing seed."""

    width: float = 0.048  # x [m]
    thickness: float = 0.006  # y [m]
    height: float = 0.12  # z [m]
    cells: tuple[int, int, int] = (12, 1, 30)
    front_back: str = "symmetry"  # fluid condition on the y faces: symmetry (pseudo-2D) or wall (no-slip)
    n_particles: int = 1000
    diameter: float = 0.002  # [m]
    density: float = 2526.0  # [kg/m^3]
    youngs_modulus: float = 1.0e6  # [Pa]
    poisson_ratio: float = 0.35
    damping: float = 0.12  # pairSpringSliderDashpot alpha (normal damping coefficient)
    friction: float = 0.3  # particle-particle and particle-wall sliding friction
    collision_resolution_steps: int = 6
    patch_restitution: float = 0.9  # rebound of a particle that still reaches a patch face
    drag: str = "ErgunWenYu"
    fluid_density: float = 1.2  # [kg/m^3]
    fluid_viscosity: float = 1.5e-5  # kinematic [m^2/s]
    alpha_max: float = 0.99  # DPMFoam alphaMax: the fluid fraction is kept >= 1 - alpha_max
    dt: float = 1.0e-4  # CFD timestep [s]; DEM substeps inside it
    snapshot_interval: float = 0.01  # [s] (one ML step)
    spinup_time: float = 0.2  # [s] simulated from the loose packing, not stored
    initial_packing_fraction: float = 0.3  # solid fraction of the loose random start packing
    write_precision: int = 8
    write_compression: bool = False  # gzip the time directories (less disk, a little more CPU)
    max_lost_particles: int = 0  # more particles leaving the domain than this: the run is failed
    max_fluid_speed: float = 50.0  # [m/s] a fluid speed beyond this anywhere is divergence
    timeout_per_simulated_s: float = 3600.0  # wall-clock limit per simulated second

    @classmethod
    def from_config(cls, cfg: Any, key: str) -> BedScene:
        values = dict(cfg)
        checks.known_keys(key, values, cls.__dataclass_fields__)
        if "cells" in values:
            cells = values["cells"]
            if isinstance(cells, str) or not hasattr(cells, "__len__") or len(cells) != 3:
                raise ConfigError(f"config value {key}.cells={cells!r} is invalid: must be [nx, ny, nz] "
                                  f"(override it, e.g. {key}.cells=[12,1,30])")
            values["cells"] = tuple(checks.positive_int(f"{key}.cells[{i}]", c) for i, c in enumerate(cells))
        scene = cls(**values)
        scene.validate(key)
        return scene

    def validate(self, key: str) -> None:
        for name in ("width", "thickness", "height", "diameter", "density", "youngs_modulus", "fluid_density",
                     "fluid_viscosity", "dt", "snapshot_interval", "max_fluid_speed", "timeout_per_simulated_s"):
            checks.positive(f"{key}.{name}", getattr(self, name))
        checks.positive_int(f"{key}.n_particles", self.n_particles)
        checks.number(f"{key}.poisson_ratio", self.poisson_ratio, lo=0.0, hi=0.5, hi_open=True)
        checks.number(f"{key}.damping", self.damping, lo=0.0, hi=1.0)
        checks.number(f"{key}.friction", self.friction, lo=0.0, hi=2.0)
        checks.positive_int(f"{key}.collision_resolution_steps", self.collision_resolution_steps)
        checks.number(f"{key}.patch_restitution", self.patch_restitution, lo=0.0, hi=1.0)
        checks.one_of(f"{key}.drag", self.drag, DRAG_MODELS)
        checks.one_of(f"{key}.front_back", self.front_back, FRONT_BACK)
        checks.number(f"{key}.alpha_max", self.alpha_max, lo=0.5, hi=1.0, hi_open=True)
        checks.number(f"{key}.spinup_time", self.spinup_time, lo=self.snapshot_interval)
        checks.number(f"{key}.initial_packing_fraction", self.initial_packing_fraction, lo=0.01, hi=0.35)
        checks.number(f"{key}.write_precision", self.write_precision, lo=6, hi=17)
        checks.positive_int(f"{key}.write_precision", self.write_precision)
        checks.positive_int(f"{key}.max_lost_particles", self.max_lost_particles, allow_zero=True)
        if min(self.width, self.thickness) < 1.5 * self.diameter:
            raise ConfigError(f"{key}: width and thickness must be at least 1.5 particle diameters "
                              f"({1.5 * self.diameter} m)")
        for name, value in (("snapshot_interval", self.snapshot_interval), ("spinup_time", self.spinup_time)):
            if not checks.is_multiple(value, self.dt):
                raise ConfigError(f"config value {key}.{name}={value} is invalid: must be a multiple of "
                                  f"{key}.dt={self.dt} (override it, e.g. {key}.{name}=...)")
        if not checks.is_multiple(self.spinup_time, self.snapshot_interval):
            raise ConfigError(f"config value {key}.spinup_time={self.spinup_time} is invalid: must be a multiple "
                              f"of {key}.snapshot_interval={self.snapshot_interval}")
        bed = self.n_particles * self.particle_volume / self.initial_packing_fraction / self.packing_area
        if bed > 0.6 * self.height:
            raise ConfigError(f"{key}: the start packing of {self.n_particles} particles at solid fraction "
                              f"{self.initial_packing_fraction} is {bed:.3f} m tall, more than 60 % of "
                              f"{key}.height={self.height}: use a taller box, fewer particles or a denser start")

    # ---- derived
    @property
    def grid(self) -> BoxGrid:
        return BoxGrid(lo=(0.0, 0.0, 0.0), hi=(self.width, self.thickness, self.height), shape=self.cells)

    @property
    def particle_volume(self) -> float:
        return math.pi / 6 * self.diameter**3

    @property
    def packing_area(self) -> float:
        """The box cross-section [m^2] (bed heights = particle volume / solid fraction / area)."""
        return self.width * self.thickness

    @property
    def minimum_fluidization_velocity(self) -> float:
        """Wen & Yu (1966) estimate of U_mf [m/s] (superficial)."""
        mu = self.fluid_viscosity * self.fluid_density
        archimedes = self.diameter**3 * self.fluid_density * (self.density - self.fluid_density) * GRAVITY / mu**2
        reynolds = math.sqrt(33.7**2 + 0.0408 * archimedes) - 33.7
        return reynolds * mu / (self.fluid_density * self.diameter)

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["cells"] = list(self.cells)
        return out


def random_packing(scene: BedScene, rng: np.random.Generator, gap: float = 0.02,
                   max_tries: int = 500) -> np.ndarray:
    """(N, 3) non-overlapping sphere centres, placed one by one uniformly at random (random sequential
    addition) in a bottom slab of the box sized for `initial_packing_fraction`; where the slab is full
    (thin boxes jam early) it grows upwards by half a diameter at a time."""
    d, r = scene.diameter, 0.5 * scene.diameter
    top = scene.n_particles * scene.particle_volume / scene.initial_packing_fraction / scene.packing_area
    lo = np.full(3, r * (1 + gap))
    hi = np.array([scene.width, scene.thickness, max(top, d)]) - lo
    hi = np.maximum(hi, lo)  # a box one particle thick in y still works
    min_dist2 = (d * (1 + gap)) ** 2
    cell = d * (1 + gap)
    buckets: dict[tuple[int, ...], list[int]] = {}
    pts = np.empty((scene.n_particles, 3))
    for n in range(scene.n_particles):
        while True:
            for _ in range(max_tries):
                p = lo + rng.random(3) * (hi - lo)
                key = tuple(int(v) for v in p // cell)
                near = [j for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)
                        for j in buckets.get((key[0] + dx, key[1] + dy, key[2] + dz), ())]
                if not near or np.min(np.sum((pts[near] - p) ** 2, axis=1)) >= min_dist2:
                    break
            else:
                hi[2] += r
                if hi[2] > scene.height - r:
                    raise ConfigError(f"data.scene: {scene.n_particles} particles do not fit into the box "
                                      "(random packing); use a taller box or fewer particles")
                continue
            break
        pts[n] = p
        buckets.setdefault(key, []).append(n)
    return pts
