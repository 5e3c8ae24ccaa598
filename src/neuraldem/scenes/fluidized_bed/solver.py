"""The fluidized bed in OpenFOAM's DPMFoam (CFD-DEM, soft-sphere collisions, four-way coupled).

Scene: a box of width x thickness x height (x, y, z; gravity -z) meshed by blockMesh into a regular grid;
air enters uniformly through the bottom (`interstitialInletVelocity`: the superficial inlet velocity U0
divided by the local fluid fraction) and leaves through a fixed-pressure top; side walls are no-slip,
front/back symmetry planes (pseudo-2D) or no-slip walls (3D). Particles: monodisperse spheres,
`pairSpringSliderDashpot` contacts resolved in `collision_resolution_steps` substeps, drag from the
`ErgunWenYu` correlation, gravity. They start at rest in a loose random packing at the bottom
(`random_packing`, a different packing per seed), fall, and are fluidized; the first `spinup_time` seconds
are simulated but not stored, so stored t = 0 is a fluidized bed.

A run (`run_fluidized_bed`) writes the case, runs blockMesh, writeCellCentres and DPMFoam serially, and
reads every time directory from the spin-up on into an `FbTrajectory`. It never raises for solver trouble:
a crash, a time-out, NaNs, a fluid speed beyond `max_fluid_speed` (divergence) or more lost particles than
`max_lost_particles` give status `failed` with the reason. Killed mid-run and started again, it resumes
DPMFoam from the latest complete time directory (incomplete ones are deleted first) and adds up the CPU
time of all attempts.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.config import checks
from neuraldem.errors import ConfigError, DataError, SolverError
from neuraldem.sim import openfoam
from neuraldem.sim.foam_reader import BoxGrid, CloudSnapshot, FoamCase, cells_to_grid, time_dirs
from neuraldem.sim.openfoam import FoamRun, run_app, write_foam_file

STATUS_OK, STATUS_FAILED = "ok", "failed"
DRAG_MODELS = ("ErgunWenYu", "WenYu", "PlessisMasliyah")
FRONT_BACK = ("symmetry", "wall")
CLOUD = "kinematicCloud"
STAMP = "neuraldem_case.json"
ATTEMPTS = "attempts.json"
GRAVITY = 9.81


@dataclass(frozen=True)
class FluidizedBedScene:
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
    def from_config(cls, cfg: Any, key: str) -> FluidizedBedScene:
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
            steps = value / self.dt
            if abs(steps - round(steps)) > 1e-6:
                raise ConfigError(f"config value {key}.{name}={value} is invalid: must be a multiple of "
                                  f"{key}.dt={self.dt} (override it, e.g. {key}.{name}=...)")
        spin = self.spinup_time / self.snapshot_interval
        if abs(spin - round(spin)) > 1e-6:
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


def random_packing(scene: FluidizedBedScene, rng: np.random.Generator, gap: float = 0.02,
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


# ---- case files


def _vec(v: tuple[float, ...] | np.ndarray) -> str:
    return "(" + " ".join(repr(float(x)) for x in v) + ")"


def write_case(scene: FluidizedBedScene, case: Path, inlet_velocity: float, positions: np.ndarray,
               end_time: float) -> None:
    """All files of a DPMFoam case in `case` (created)."""
    W, T, H = scene.width, scene.thickness, scene.height
    nx, ny, nz = scene.cells
    write_foam_file(case / "system" / "blockMeshDict", "dictionary", "blockMeshDict", f"""scale 1;
vertices
(
    (0 0 0) ({W!r} 0 0) ({W!r} {T!r} 0) (0 {T!r} 0)
    (0 0 {H!r}) ({W!r} 0 {H!r}) ({W!r} {T!r} {H!r}) (0 {T!r} {H!r})
);
blocks (hex (0 1 2 3 4 5 6 7) ({nx} {ny} {nz}) simpleGrading (1 1 1));
edges ();
boundary
(
    bottom {{ type wall; faces ((0 3 2 1)); }}
    top {{ type wall; faces ((4 5 6 7)); }}
    walls {{ type wall; faces ((0 4 7 3) (1 2 6 5)); }}
    frontAndBack {{ type {'symmetry' if scene.front_back == 'symmetry' else 'wall'}; faces ((0 1 5 4) (3 7 6 2)); }}
);
""")
    sym = scene.front_back == "symmetry"
    fb_u = "type symmetry;" if sym else "type noSlip;"
    fb_p = "type symmetry;" if sym else "type fixedFluxPressure; value uniform 0;"
    u0 = f"(0 0 {float(inlet_velocity)!r})"
    write_foam_file(case / "0" / "U.air", "volVectorField", "U.air", f"""dimensions [0 1 -1 0 0 0 0];
internalField uniform (0 0 0);
boundaryField
{{
    bottom
    {{
        type interstitialInletVelocity;   // superficial inlet velocity / fluid fraction
        inletVelocity uniform {u0};
        value uniform {u0};
        phi phi.air;
        alpha alpha.air;
    }}
    top {{ type pressureInletOutletVelocity; phi phi.air; inletValue uniform (0 0 0); value uniform (0 0 0); }}
    walls {{ type noSlip; }}
    frontAndBack {{ {fb_u} }}
}}
""", location="0")
    write_foam_file(case / "0" / "p", "volScalarField", "p", f"""dimensions [0 2 -2 0 0 0 0];
internalField uniform 0;
boundaryField
{{
    bottom {{ type fixedFluxPressure; value uniform 0; }}
    top {{ type fixedValue; value uniform 0; }}
    walls {{ type fixedFluxPressure; value uniform 0; }}
    frontAndBack {{ {fb_p} }}
}}
""", location="0")
    write_foam_file(case / "constant" / "g", "uniformDimensionedVectorField", "g",
                    f"dimensions [0 1 -2 0 0 0 0];\nvalue (0 0 {-GRAVITY!r});\n", location="constant")
    write_foam_file(case / "constant" / "transportProperties", "dictionary", "transportProperties",
                    f"continuousPhase air;\nrho.air {scene.fluid_density!r};\ntransportModel Newtonian;\n"
                    f"nu {scene.fluid_viscosity!r};\n", location="constant")
    write_foam_file(case / "constant" / "turbulenceProperties.air", "dictionary", "turbulenceProperties.air",
                    "simulationType laminar;\n", location="constant")
    write_foam_file(case / "constant" / "kinematicCloudPositions", "vectorField", "kinematicCloudPositions",
                    f"{len(positions)}\n(\n" + "".join(f"({x!r} {y!r} {z!r})\n" for x, y, z in positions.tolist())
                    + ")\n", location="constant")
    _write_cloud_properties(scene, case)
    _write_system(scene, case, end_time)


def _write_cloud_properties(scene: FluidizedBedScene, case: Path) -> None:
    rebound = "".join(f"        {p} {{ type rebound; e {scene.patch_restitution!r}; mu {scene.friction!r}; }}\n"
                      for p in ("bottom", "top", "walls", "frontAndBack"))
    contact = (f"alpha {scene.damping!r}; b 1.5; mu {scene.friction!r}; cohesionEnergyDensity 0; "
               f"collisionResolutionSteps {scene.collision_resolution_steps};")
    write_foam_file(case / "constant" / "kinematicCloudProperties", "dictionary", "kinematicCloudProperties", f"""
solution
{{
    active true;
    coupled true;
    transient yes;
    cellValueSourceCorrection off;
    interpolationSchemes {{ rho.air cell; U.air cellPoint; mu.air cell; }}
    integrationSchemes {{ U Euler; }}
    sourceTerms {{ schemes {{ U semiImplicit 1; }} }}
}}
constantProperties
{{
    parcelTypeId 1;
    rhoMin 1e-15;
    minParcelMass 1e-15;
    rho0 {scene.density!r};
    youngsModulus {scene.youngs_modulus!r};
    poissonsRatio {scene.poisson_ratio!r};
    constantVolume false;
    alphaMax {scene.alpha_max!r};
}}
subModels
{{
    particleForces
    {{
        {scene.drag}Drag {{ alphac alpha.air; }}
        gravity;
    }}
    injectionModels
    {{
        start
        {{
            type manualInjection;
            massTotal 0;
            parcelBasisType fixed;
            nParticle 1;
            SOI 0;
            positionsFile "kinematicCloudPositions";
            U0 (0 0 0);
            sizeDistribution {{ type fixedValue; fixedValueDistribution {{ value {scene.diameter!r}; }} }}
        }}
    }}
    dispersionModel none;
    patchInteractionModel localInteraction;
    localInteractionCoeffs
    {{
        patches
        (
{rebound}        );
    }}
    heatTransferModel none;
    surfaceFilmModel none;
    collisionModel pairCollision;
    pairCollisionCoeffs
    {{
        maxInteractionDistance {scene.diameter!r};
        writeReferredParticleCloud no;
        pairModel pairSpringSliderDashpot;
        pairSpringSliderDashpotCoeffs {{ useEquivalentSize no; {contact} }}
        wallModel wallSpringSliderDashpot;
        wallSpringSliderDashpotCoeffs
        {{
            useEquivalentSize no; youngsModulus {scene.youngs_modulus!r}; poissonsRatio {scene.poisson_ratio!r};
            {contact}
        }}
        U U.air;
    }}
    stochasticCollisionModel none;
    radiation off;
}}
cloudFunctions {{}}
""", location="constant")


def _write_system(scene: FluidizedBedScene, case: Path, end_time: float) -> None:
    # Air volume flow through bottom and top in every step: sum over the patch faces of
    # alpha.air * phi.air (fluid fraction times the interstitial flux, both after the pressure correction).
    # The solver's own alphaPhi.air field is not used: it is set before the pressure correction.
    monitors = "".join(f"""
    flux_{patch}
    {{
        type surfaceFieldValue;
        libs ("libfieldFunctionObjects.so");
        writeControl timeStep;
        writeInterval 1;
        log false;
        writeFields false;
        regionType patch;
        name {patch};
        operation weightedSum;
        weightField alpha.air;
        fields (phi.air);
    }}""" for patch in ("bottom", "top"))
    write_foam_file(case / "system" / "controlDict", "dictionary", "controlDict", f"""application DPMFoam;
startFrom latestTime;
startTime 0;
stopAt endTime;
endTime {end_time!r};
deltaT {scene.dt!r};
writeControl timeStep;
writeInterval {round(scene.snapshot_interval / scene.dt)};
purgeWrite 0;
writeFormat ascii;
writePrecision {scene.write_precision};
writeCompression {'on' if scene.write_compression else 'off'};
timeFormat general;
timePrecision 8;
runTimeModifiable no;
functions
{{{monitors}
}}
""", location="system")
    write_foam_file(case / "system" / "fvSchemes", "dictionary", "fvSchemes", """
ddtSchemes { default Euler; }
gradSchemes { default Gauss linear; }
divSchemes
{
    default none;
    div(alphaPhi.air,U.air) Gauss linearUpwindV unlimited;
    div(((alpha.air*nuEff.air)*dev2(T(grad(U.air))))) Gauss linear;
    div(phiGByA,kinematicCloud:alpha) Gauss linear;
}
laplacianSchemes { default Gauss linear corrected; }
interpolationSchemes { default linear; }
snGradSchemes { default corrected; }
""", location="system")
    write_foam_file(case / "system" / "fvSolution", "dictionary", "fvSolution", """
solvers
{
    p { solver GAMG; tolerance 1e-7; relTol 0.01; smoother GaussSeidel; }
    pFinal { solver GAMG; tolerance 1e-7; relTol 0; smoother GaussSeidel; }
    "U.air.*" { solver smoothSolver; smoother symGaussSeidel; tolerance 1e-6; relTol 0; }
    kinematicCloud:alpha { solver smoothSolver; smoother symGaussSeidel; tolerance 1e-6; relTol 0; }
}
PIMPLE
{
    nOuterCorrectors 1;
    nCorrectors 2;
    momentumPredictor yes;
    nNonOrthogonalCorrectors 0;
    pRefCell 0;
    pRefValue 0;
}
relaxationFactors {}
""", location="system")


# ---- a trajectory read back from the case


@dataclass
class FbTrajectory:
    """Stored snapshots of one run; t = 0 is the end of the spin-up (solver time `t0`)."""

    times: np.ndarray  # (T,) [s]
    t0: float  # solver time of t = 0
    orig_proc: np.ndarray  # (N,) int64, particle identity = (orig_proc, orig_id), sorted
    orig_id: np.ndarray  # (N,) int64
    diameters: np.ndarray  # (N,) [m]
    density: float  # particle density [kg/m^3]
    positions: np.ndarray  # (T, N, 3) [m]; NaN once a particle has left the domain
    velocities: np.ndarray  # (T, N, 3) [m/s]; NaN likewise
    lost_time: np.ndarray  # (N,) first snapshot time the particle was missing; NaN = never lost
    grid: BoxGrid
    fluid_velocity: np.ndarray  # (T, nx, ny, nz, 3) interstitial air velocity U.air [m/s]
    fluid_fraction: np.ndarray  # (T, nx, ny, nz) the solver's alpha.air (particle volume binned per cell)
    pressure: np.ndarray  # (T, nx, ny, nz) kinematic pressure p [m^2/s^2]
    inflow: np.ndarray  # (T,) air volume flow in through the bottom at each snapshot step [m^3/s]
    outflow: np.ndarray  # (T,) air volume flow out through the top [m^3/s]
    grid_mapping: str = "exact"  # how mesh cells were mapped onto the grid (exact / nearest)

    @property
    def n_particles(self) -> int:
        return len(self.orig_id)

    def counts(self) -> np.ndarray:
        return np.isfinite(self.positions[..., 0]).sum(axis=1)


def read_flux_monitor(case: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(times, values) of a surfaceFieldValue monitor over all restarts (later runs win on overlap)."""
    rows: dict[float, float] = {}
    base = case / "postProcessing" / name
    if not base.is_dir():
        return np.empty(0), np.empty(0)
    for _, start in time_dirs(base):
        path = base / start / "surfaceFieldValue.dat"
        if not path.is_file():
            continue
        for line in path.read_text(errors="replace").splitlines():
            parts = line.split()
            if not parts or line.startswith("#") or len(parts) < 2:
                continue
            try:
                rows[float(parts[0])] = float(parts[1])
            except ValueError:
                continue  # a line cut by a kill
    t = np.array(sorted(rows))
    return t, np.array([rows[k] for k in t])


def read_trajectory(case: FoamCase, grid: BoxGrid, t0: float, snapshot_interval: float,
                    n_snapshots: int | None = None, density: float = float("nan"),
                    cloud_reader: Callable[[str], CloudSnapshot] | None = None) -> FbTrajectory:
    """Snapshots from solver time `t0` on (every `snapshot_interval`; time directories in between are
    skipped) into dense arrays. The particles present at t0 define the particle set; particles missing
    later are lost (NaN from then on, `lost_time` set), particles that appear later are an error; an
    unreadable time directory is an error naming the file.
    `cloud_reader`: where the particles of a time directory come from (default: its lagrangian cloud)."""
    read_cloud = cloud_reader or case.cloud
    eps = 1e-6 * snapshot_interval
    names = []
    for value, name in case.times():
        k = (value - t0) / snapshot_interval
        if value >= t0 - eps and abs(k - round(k)) < 1e-4:
            names.append((round(k), value, name))
    if not names:
        raise DataError(f"{case.path}: no time directory at or after t = {t0} s")
    if names[0][0] != 0:
        raise DataError(f"{case.path}: no time directory at t0 = {t0} s (first stored one: {names[0][1]})")
    ks = [k for k, _, _ in names]
    if ks != list(range(len(ks))):
        missing = sorted(set(range(ks[-1] + 1)) - set(ks))
        raise DataError(f"{case.path}: time directories missing at t = "
                        f"{[round(t0 + k * snapshot_interval, 9) for k in missing[:5]]} s")
    if n_snapshots is not None:
        names = names[:n_snapshots]
    idx, mapping = cells_to_grid(case.cell_centres(), grid)
    first = read_cloud(names[0][2])
    keys0 = first.keys
    N, Tn = len(first), len(names)
    pos = np.full((Tn, N, 3), np.nan)
    vel = np.full((Tn, N, 3), np.nan)
    U = np.empty((Tn, *grid.shape, 3))
    alpha = np.empty((Tn, *grid.shape))
    p = np.empty((Tn, *grid.shape))
    lost = np.full(N, np.nan)
    times = []
    for t, (k, _, name) in enumerate(names):
        snap = first if t == 0 else read_cloud(name)
        U[t] = case.cell_field(name, "fluid_velocity")[idx]
        alpha[t] = case.cell_field(name, "fluid_fraction")[idx]
        p[t] = case.cell_field(name, "pressure")[idx]
        where = np.searchsorted(keys0, snap.keys)
        known = (where < N) & (keys0[np.minimum(where, N - 1)] == snap.keys)
        if not known.all():
            raise DataError(f"{case.cloud_dir(name)}: {int((~known).sum())} particle(s) that were not present "
                            f"at t0 = {t0} s appeared (an injection after the spin-up?)")
        pos[t, where] = snap.positions
        assert snap.velocities is not None
        vel[t, where] = snap.velocities
        missing = ~np.isfinite(pos[t, :, 0]) & ~np.isfinite(lost)
        lost[missing] = round(k * snapshot_interval, 9)
        times.append(round(k * snapshot_interval, 9))
    if np.any(np.isfinite(pos[:, :, 0]) & np.isfinite(lost)[None, :]
              & (np.asarray(times)[:, None] >= np.nan_to_num(lost, nan=np.inf)[None, :])):
        raise DataError(f"{case.path}: a particle reappears after it was lost")
    ft_in, f_in = read_flux_monitor(case.path, "flux_bottom")
    ft_out, f_out = read_flux_monitor(case.path, "flux_top")
    solver_times = np.array([t0 + t for t in times])
    return FbTrajectory(
        times=np.asarray(times), t0=t0, orig_proc=first.orig_proc, orig_id=first.orig_id,
        diameters=first.diameters, density=density, positions=pos, velocities=vel, lost_time=lost, grid=grid,
        fluid_velocity=U, fluid_fraction=alpha, pressure=p,
        inflow=-_at_times(ft_in, f_in, solver_times), outflow=_at_times(ft_out, f_out, solver_times),
        grid_mapping=mapping)


def _at_times(t: np.ndarray, v: np.ndarray, want: np.ndarray) -> np.ndarray:
    """Monitor values at the snapshot times (NaN where the monitor has no entry)."""
    out = np.full(len(want), np.nan)
    if len(t) == 0:
        return out
    hi = np.clip(np.searchsorted(t, want), 0, len(t) - 1)
    lo = np.clip(hi - 1, 0, len(t) - 1)
    i = np.where(np.abs(t[lo] - want) < np.abs(t[hi] - want), lo, hi)
    ok = np.abs(t[i] - want) < 1e-7 + 1e-9 * np.abs(want)
    out[ok] = v[i[ok]]
    return out


# ---- running a case


@dataclass
class FbRunResult:
    status: str
    reason: str
    trajectory: FbTrajectory | None
    cost: dict[str, float] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)


def case_stamp(scene: FluidizedBedScene, inlet_velocity: float, duration: float, seed: int) -> dict[str, Any]:
    return {"scene": scene.as_dict(), "inlet_velocity": float(inlet_velocity), "duration": float(duration),
            "seed": int(seed)}


def latest_complete_time(case: FoamCase) -> str | None:
    """Delete incomplete time directories from the end (a killed run's last write); return the latest
    complete one after the initial one (None: start from scratch)."""
    for value, name in reversed(time_dirs(case.path)):
        if value <= 0:
            return None
        reason = case.check_time(name)
        if reason is None:
            return name
        shutil.rmtree(case.path / name)
    return None


def prepare_case(scene: FluidizedBedScene, workdir: Path, inlet_velocity: float, duration: float,
                 seed: int) -> tuple[bool, str | None]:
    """Write a fresh case, or keep a started one with the same settings. Returns (resumed, restart time)."""
    stamp = case_stamp(scene, inlet_velocity, duration, seed)
    stamp_path = workdir / STAMP
    if stamp_path.is_file():
        try:
            same = json.loads(stamp_path.read_text()) == json.loads(json.dumps(stamp))
        except json.JSONDecodeError:
            same = False
        if same and (workdir / "constant" / "polyMesh" / "owner").is_file() and (workdir / "0" / "C").is_file():
            restart = latest_complete_time(FoamCase(workdir))
            if restart is not None:
                _record_killed_attempts(workdir)
                return True, restart
    if workdir.exists():
        shutil.rmtree(workdir)
    workdir.mkdir(parents=True)
    positions = random_packing(scene, np.random.default_rng(seed))
    write_case(scene, workdir, inlet_velocity, positions, end_time=round(scene.spinup_time + duration, 9))
    stamp_path.write_text(json.dumps(stamp, indent=1))
    return False, None


def _record_attempt(workdir: Path, run: FoamRun, restart: str | None,
                    load: tuple[float, float] | None = None) -> list[dict[str, Any]]:
    """Append one app run (CPU, wall, the machine's 1-min load average before and after) to attempts.json."""
    path = workdir / ATTEMPTS
    attempts = json.loads(path.read_text()) if path.is_file() else []
    attempts.append({"app": run.app, "cpu_s": run.cpu_s, "wall_s": run.wall_s, "returncode": run.returncode,
                     "restart_from": restart, "max_rss_mb": run.max_rss_mb,
                     "load_avg": list(load) if load else None, "log": run.log_path.name})
    path.write_text(json.dumps(attempts, indent=1))
    return attempts


_EXECUTION = re.compile(r"^ExecutionTime = ([\d.eE+-]+) s\s+ClockTime = ([\d.eE+-]+) s", re.MULTILINE)


def _record_killed_attempts(workdir: Path) -> None:
    """A DPMFoam killed with its driver never got its attempt recorded: take its CPU time from the last
    `ExecutionTime` line of its log (OpenFOAM's CPU time of the process)."""
    path = workdir / ATTEMPTS
    attempts = json.loads(path.read_text()) if path.is_file() else []
    known = {str(a.get("log")).removesuffix(".gz") for a in attempts}
    for log in sorted(workdir.glob("log.DPMFoam*")):
        if log.name.removesuffix(".gz") in known or log.suffix == ".gz":
            continue
        times = _EXECUTION.findall(log.read_text(errors="replace"))
        cpu, wall = (float(times[-1][0]), float(times[-1][1])) if times else (0.0, 0.0)
        attempts.append({"app": "DPMFoam", "cpu_s": cpu, "wall_s": wall, "returncode": None, "restart_from": None,
                         "max_rss_mb": 0.0, "load_avg": None, "log": log.name, "killed": True})
    path.write_text(json.dumps(attempts, indent=1))


def _mesh(workdir: Path, timeout_s: float) -> None:
    if not (workdir / "constant" / "polyMesh" / "owner").is_file():
        run = run_app("blockMesh", workdir, timeout_s=timeout_s)
        _record_attempt(workdir, run, None)
        openfoam.require_ok(run, "blockMesh")
    if not (workdir / "0" / "C").is_file():
        run = run_app("postProcess", workdir, ("-func", "writeCellCentres", "-time", "0"),
                      log_name="log.writeCellCentres", timeout_s=timeout_s)
        _record_attempt(workdir, run, None)
        openfoam.require_ok(run, "postProcess -func writeCellCentres")


_SUBCYCLES = re.compile(r"^\s*(\d+)\s+move-collide subCycles", re.MULTILINE)
_STEP = re.compile(r"^Time = ", re.MULTILINE)


def run_fluidized_bed(scene: FluidizedBedScene, inlet_velocity: float, duration: float, workdir: Path,
                      seed: int) -> FbRunResult:
    """Run (or resume) one trajectory of `duration` stored seconds after the spin-up; never raises for
    solver trouble (status failed + reason), only for a missing OpenFOAM or bad settings."""
    openfoam.find_apps()
    openfoam.foam_env()
    sim_time = scene.spinup_time + duration
    timeout = scene.timeout_per_simulated_s * sim_time
    resumed, restart = prepare_case(scene, workdir, inlet_velocity, duration, seed)
    try:
        _mesh(workdir, timeout)
    except SolverError as err:
        return FbRunResult(STATUS_FAILED, str(err), None, _cost(workdir, sim_time))
    load0 = os.getloadavg()[0]
    n_logs = len(list(workdir.glob("log.DPMFoam*")))
    run = run_app("DPMFoam", workdir, timeout_s=timeout,
                  log_name="log.DPMFoam" if n_logs == 0 else f"log.DPMFoam.{n_logs}.restart_{restart}")
    _record_attempt(workdir, run, restart, (load0, os.getloadavg()[0]))
    cost = _cost(workdir, sim_time)
    diagnostics: dict[str, Any] = {"resumed_from": restart} if resumed else {}
    log = run.log
    subcycles = [int(x) for x in _SUBCYCLES.findall(log)]
    n_steps = len(_STEP.findall(log))
    if n_steps:  # steps without the message have one move-collide cycle
        substeps = (sum(subcycles) + n_steps - len(subcycles)) / n_steps
        diagnostics["mean_collision_substeps"] = substeps
        # particle-steps of the whole run at this attempt's mean substep count (the hopper's cost unit)
        cost["particle_steps"] = scene.n_particles * round(sim_time / scene.dt) * substeps
    if run.error:
        return FbRunResult(STATUS_FAILED, f"DPMFoam: {run.error}", None, cost, diagnostics)
    result = finish(scene, FoamCase(workdir), duration, cost, diagnostics)
    if result.status == STATUS_OK:
        compress_logs(workdir)
    return result


def compress_logs(workdir: Path) -> None:
    """gzip the DPMFoam logs of a finished run (DPMFoam prints ~2.5 kB per step: 0.75 GB for 30 s)."""
    import gzip

    for log in workdir.glob("log.DPMFoam*"):
        if log.suffix == ".gz":
            continue
        with open(log, "rb") as src, gzip.open(log.with_name(log.name + ".gz"), "wb") as dst:
            shutil.copyfileobj(src, dst)
        log.unlink()


def finish(scene: FluidizedBedScene, case: FoamCase, duration: float, cost: dict[str, float],
           diagnostics: dict[str, Any]) -> FbRunResult:
    """Read the finished case and classify it: ok, or failed (incomplete, diverged, particles lost)."""
    n_snap = round(duration / scene.snapshot_interval) + 1
    try:
        traj = read_trajectory(case, scene.grid, scene.spinup_time, scene.snapshot_interval, n_snap,
                               density=scene.density)
    except DataError as err:
        reason = str(err)
        if "NaN" in reason:
            reason = f"diverged: {reason}"
        return FbRunResult(STATUS_FAILED, reason, None, cost, diagnostics)
    if len(traj.times) < n_snap:
        return FbRunResult(STATUS_FAILED, f"{case.path}: only {len(traj.times)} of {n_snap} snapshots written",
                           None, cost, diagnostics)
    if traj.grid_mapping != "exact":
        return FbRunResult(STATUS_FAILED, f"{case.path}: mesh cell centres do not match the scene grid", None,
                           cost, diagnostics)
    n_lost = int(np.isfinite(traj.lost_time).sum())
    escaped = case.escaped_parcels(case.times()[-1][1])
    speed = float(np.max(np.linalg.norm(traj.fluid_velocity, axis=-1)))
    imbalance = np.abs(traj.inflow - traj.outflow) / np.maximum(np.abs(traj.inflow), 1e-30)
    diagnostics.update({
        "n_particles": traj.n_particles, "n_lost": n_lost, "escaped_parcels": escaped,
        "max_fluid_speed": speed, "max_flux_imbalance": float(np.nanmax(imbalance)) if imbalance.size else None,
        "min_solver_fluid_fraction": float(traj.fluid_fraction.min()),
    })
    if traj.n_particles != scene.n_particles:
        lost_in_spinup = scene.n_particles - traj.n_particles
        diagnostics["n_lost_in_spinup"] = lost_in_spinup
        n_lost += lost_in_spinup
    if speed > scene.max_fluid_speed:
        return FbRunResult(STATUS_FAILED, f"diverged: fluid speed {speed:.3g} m/s > max_fluid_speed "
                           f"{scene.max_fluid_speed} m/s", traj, cost, diagnostics)
    if n_lost > scene.max_lost_particles:
        first = float(np.nanmin(traj.lost_time)) if np.isfinite(traj.lost_time).any() else -scene.spinup_time
        return FbRunResult(STATUS_FAILED, f"{n_lost} particle(s) left the domain (first at t = {first:g} s; "
                           f"max_lost_particles = {scene.max_lost_particles})", traj, cost, diagnostics)
    return FbRunResult(STATUS_OK, "", traj, cost, diagnostics)


def _cost(workdir: Path, sim_time: float) -> dict[str, float]:
    path = workdir / ATTEMPTS
    attempts = json.loads(path.read_text()) if path.is_file() else []
    cpu = float(sum(a["cpu_s"] for a in attempts))
    solver_cpu = float(sum(a["cpu_s"] for a in attempts if a["app"] == "DPMFoam"))
    solver_wall = float(sum(a["wall_s"] for a in attempts if a["app"] == "DPMFoam"))
    return {"cpu_s": cpu, "solver_cpu_s": solver_cpu, "wall_s": float(sum(a["wall_s"] for a in attempts)),
            "solver_wall_s": solver_wall,
            "simulated_s": float(sim_time), "cpu_s_per_simulated_s": solver_cpu / sim_time,
            "attempts": float(sum(1 for a in attempts if a["app"] == "DPMFoam")),
            "max_rss_mb": float(max((a["max_rss_mb"] for a in attempts), default=0.0)),
            "load_avg": float(np.mean([x for a in attempts if a["app"] == "DPMFoam" for x in (a.get("load_avg") or [])]
                                      or [np.nan]))}


def remove_time_dirs(case: Path) -> None:
    """Free the disk after conversion: the time directories (keep 0, logs, postProcessing, system)."""
    for value, name in time_dirs(case):
        if value > 0:
            shutil.rmtree(case / name)
