"""Lifted-cylinder heap test: the angle of repose of a material.

An open tube (radius `tube_radius`) stands on a flat base of the same material. The spheres are poured into
it and settle; then the tube is lifted slowly (`lift_speed`) by `lift_height`, the material slumps out and
forms a conical heap, which relaxes for `rest_time` with the tube out of the way. The final positions are
binned in annuli around the tube axis; the heap surface h(r) is the highest particle top in each annulus
and the angle of repose is the slope of a straight line fitted to the flank, i.e. to the annuli (outside
the central `fit_min_radius`) whose surface lies between `fit_band[0]` and `fit_band[1]` of the heap height:

    repose = atan(-dh/dr)

No heap: a material with very little friction (e.g. mu_s 0.1, mu_r 0.05) spreads into a layer one or two
particles thick. Its flank then has fewer than `fit_min_points` annuli and the test returns the aspect angle
of the spread pile instead, atan(heap height / runout radius) (runout = 95th percentile of the particle
radii) with `heap_formed = False`: a small positive angle of a few degrees, never NaN.

Particles that roll out of the domain (half width `domain_half_width`) are dropped and counted (`n_lost`);
without rolling friction (mu_r = 0) and with little sliding friction most of them roll away for good, and
the few left give a repose angle of ~0 (the runout then is bounded by the domain).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.config import checks
from neuraldem.errors import ConfigError, SolverError
from neuraldem.sim.material import Material
from neuraldem.sim.runner import SolverRun
from neuraldem.sim.shear import (
    GRAVITY,
    INSERT_FRACTION,
    PresetSettings,
    box_input,
    check_seed,
    missing_output,
    pour_input,
    read_info,
    run_input,
)
from neuraldem.sim.stl import polyline, revolve, write_stl

# settled solid fraction used to estimate the fill height of the tube (a random packing is 0.55-0.64)
_SETTLED_FRACTION = 0.6


@dataclass(frozen=True)
class HeapSettings(PresetSettings):
    """Heap-test settings. The defaults are the "small" production preset for the 10 mm hopper material
    (~25-35 CPU-s per test); `HeapSettings.tiny()` is a few CPU-s for tests (coarser, a few deg)."""

    n_particles: int = 2000
    tube_radius: float = 8.0  # [particle diameters]; the fill height is about one radius
    lift_speed: float = 0.05  # [m/s]; fast lifts throw the material out and give too flat heaps
    lift_height: float = 11.0  # how far the tube is lifted [d]; must clear the fill
    settle_time: float = 0.5  # pour + settle inside the tube [s]
    rest_time: float = 0.7  # relaxation after the lift [s]
    domain_half_width: float = 30.0  # particles beyond this radius in x or y are dropped [d]
    tube_segments: int = 32  # facets around the tube mesh
    bin_width: float = 1.0  # annulus width for the surface profile [d]
    fit_band: tuple[float, float] = (0.2, 0.8)  # flank = surface between these fractions of the height
    fit_min_radius: float = 2.0  # annuli closer to the axis than this belong to the cap [d]
    fit_min_points: int = 3  # fewer flank annuli -> "no heap", aspect-angle fallback
    min_heap_height: float = 2.0  # lower piles (above the first particle layer) count as "no heap" [d]
    seed: int = 67867967  # packing seed (prime > 10000)

    @classmethod
    def tiny(cls) -> HeapSettings:
        """A few CPU seconds: 500 particles in a 5 d tube, shorter settle/lift/rest. Coarser (few deg)."""
        return cls(n_particles=500, tube_radius=5.0, lift_speed=0.1, lift_height=8.0, settle_time=0.35,
                   rest_time=0.4, domain_half_width=20.0, tube_segments=24)

    @classmethod
    def from_config(cls, cfg: Any, key: str) -> HeapSettings:
        """From a mapping such as `data.characterization.heap`: `preset` (small | tiny) + overrides."""
        if cfg is not None and "fit_band" in cfg:
            cfg = {**{str(k): v for k, v in cfg.items()}, "fit_band": tuple(checks.interval(
                f"{key}.fit_band", cfg["fit_band"]))}
        return super().from_config(cfg, key)

    def fill_height(self) -> float:
        """Estimated height of the settled fill in the tube [d]."""
        r_in = self.tube_radius - 0.5
        return self.n_particles / (6.0 * _SETTLED_FRACTION * r_in * r_in)  # N (pi/6) / (phi pi r^2)

    def validate(self, key: str = "heap") -> None:
        checks.positive_int(f"{key}.n_particles", self.n_particles)
        checks.number(f"{key}.tube_radius", self.tube_radius, lo=2.0)
        checks.positive(f"{key}.lift_speed", self.lift_speed)
        checks.positive(f"{key}.lift_height", self.lift_height)
        checks.positive(f"{key}.settle_time", self.settle_time)
        checks.number(f"{key}.rest_time", self.rest_time, lo=0.0)
        checks.number(f"{key}.domain_half_width", self.domain_half_width, lo=2.0 * self.tube_radius)
        checks.positive_int(f"{key}.tube_segments", self.tube_segments)
        checks.number(f"{key}.tube_segments", self.tube_segments, lo=8)
        checks.positive(f"{key}.bin_width", self.bin_width)
        lo, hi = checks.interval(f"{key}.fit_band", self.fit_band)
        if not 0.0 <= lo < hi <= 1.0:
            raise ConfigError(f"config value {key}.fit_band={self.fit_band!r} is invalid: needs "
                              f"0 <= lo < hi <= 1 (override it, e.g. {key}.fit_band=[0.2,0.8])")
        checks.number(f"{key}.fit_min_radius", self.fit_min_radius, lo=0.0)
        checks.positive_int(f"{key}.fit_min_points", self.fit_min_points)
        checks.number(f"{key}.fit_min_points", self.fit_min_points, lo=2)
        checks.number(f"{key}.min_heap_height", self.min_heap_height, lo=0.0)
        check_seed(f"{key}.seed", self.seed)
        fill = self.fill_height()
        if self.lift_height < fill:
            raise ConfigError(
                f"config value {key}.lift_height={self.lift_height!r} is invalid: the tube must clear the "
                f"fill, ~{fill:.1f} particle diameters high for {key}.n_particles={self.n_particles} "
                f"(override it, e.g. {key}.lift_height={math.ceil(fill) + 1})")

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["fit_band"] = list(self.fit_band)
        return out


@dataclass(frozen=True)
class HeapResult:
    repose_deg: float  # flank slope angle, or the aspect-angle fallback when no heap formed
    heap_formed: bool  # False: fewer than fit_min_points flank annuli (material spread out)
    heap_height: float  # surface height at the axis, above the first particle layer [d]
    runout_radius: float  # 95th percentile of the particle distance from the axis [d]
    fit_r2: float  # coefficient of determination of the flank fit (nan without a fit)
    fit_rmse: float  # rms deviation of the flank points from the line [d] (nan without a fit)
    n_fit: int  # flank annuli in the fit
    n_particles: int  # left in the domain at the end
    n_lost: int  # rolled out of the domain (most of them for mu_r = 0 and low mu_s)
    max_speed: float  # largest particle speed at the end [m/s]: ~0 for a heap at rest
    cpu_s: float
    wall_s: float

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def write_tube(material: Material, s: HeapSettings, path: Path) -> None:
    """Open cylinder (no bottom) of radius tube_radius, as tall as the insertion region, as ASCII STL."""
    d = material.diameter
    radius = s.tube_radius * d
    height = _insert_height(material, s) + 2.0 * d
    edge = 2.0 * math.pi * radius / s.tube_segments
    write_stl(path, revolve(polyline((radius, 0.0), (radius, height), edge), s.tube_segments), "tube")


def _insert_height(material: Material, s: HeapSettings) -> float:
    r_in = (s.tube_radius - 0.6) * material.diameter
    volume = s.n_particles * math.pi / 6.0 * material.diameter ** 3
    return volume / (INSERT_FRACTION * math.pi * r_in * r_in) + material.diameter


def heap_input(material: Material, s: HeapSettings) -> str:
    """The LIGGGHTS input of one heap test (all values from the material and the settings)."""
    d = material.diameter
    half = s.domain_half_width * d
    z_ins = _insert_height(material, s)
    z_top = z_ins + 2.0 * d + s.lift_height * d + 0.05
    lift_time = s.lift_height * d / s.lift_speed
    steps = {name: max(1, round(t / material.dt)) for name, t in
             (("settle", s.settle_time), ("lift", lift_time), ("rest", s.rest_time))}
    rest_run = f"run {steps['rest']}\n" if s.rest_time > 0 else ""
    return f"""\
# neuraldem lifted-cylinder heap: angle of repose (written by neuraldem.sim.heap)
{box_input(material, "f f f", (-half, -half, -0.5 * d), (half, half, z_top), n_types=2)}
fix grav all gravity {GRAVITY} vector 0.0 0.0 -1.0
# base plane and tube wall (type 2) with the particles' own contact law
fix base all wall/gran {material.wall_model} primitive type 2 zplane 0.0
fix tube all mesh/surface file tube.stl type 2
fix tubewall all wall/gran {material.wall_model} mesh n_meshes 1 meshes tube

# ---- 1. pour into the tube and settle
region fillreg cylinder z 0.0 0.0 {(s.tube_radius - 0.6) * d!r} {d!r} {z_ins!r} units box
{pour_input(material, s.seed, s.n_particles)}
thermo 2000
thermo_modify lost ignore norm no
run {steps['settle']}
unfix fill
variable nfill equal count(all)
variable nfill0 equal ${{nfill}}

# ---- 2. lift the tube
fix lift all move/mesh mesh tube linear 0.0 0.0 {s.lift_speed!r}
run {steps['lift']}
unfix lift
unfix tubewall

# ---- 3. let the heap come to rest
{rest_run}variable nend equal count(all)
print "nfill ${{nfill0}} nend ${{nend}}" file info.txt
write_dump all custom heap_final.txt id x y z radius vx vy vz
"""


def _read_dump(path: Path, what: str) -> np.ndarray:
    if not path.exists():
        raise missing_output(path, what)
    text = path.read_text()
    if "ITEM: ATOMS" not in text:
        raise SolverError(f"{what}: {path} is not a LIGGGHTS dump")
    body = text.split("ITEM: ATOMS", 1)[1].partition("\n")[2]
    values = np.array(body.split(), dtype=float)
    if values.size % 8:
        raise SolverError(f"{what}: {path} is truncated")
    return values.reshape(-1, 8)


def fit_heap(x: np.ndarray, y: np.ndarray, z_top: np.ndarray, d: float, s: HeapSettings) -> dict[str, Any]:
    """Angle of repose from final particle positions (x, y around the tube axis; z_top = centre + radius).

    Heights are measured above the first particle layer (z_top - d), so a spread monolayer has height 0.
    Returns repose_deg, heap_formed, heap_height, runout_radius (both in d), fit_r2, fit_rmse, n_fit."""
    if len(x) == 0:  # everything rolled out of the domain (no rolling friction): certainly no heap
        return dict(heap_height=0.0, runout_radius=s.domain_half_width, n_fit=0, fit_r2=float("nan"),
                    fit_rmse=float("nan"), repose_deg=0.0, heap_formed=False)
    r = np.hypot(x, y) / d
    t = z_top / d - 1.0  # thickness above one layer of particles lying on the base
    runout = float(np.percentile(r, 95))
    n_bins = int(math.ceil(r.max() / s.bin_width)) + 1
    idx = np.minimum((r / s.bin_width).astype(int), n_bins - 1)
    surface = np.full(n_bins, -np.inf)
    np.maximum.at(surface, idx, t)
    centres = (np.arange(n_bins) + 0.5) * s.bin_width
    cap = centres <= max(s.fit_min_radius, s.bin_width)
    height = max(0.0, float(surface[cap].max()))
    # the heap is the contiguous run of occupied annuli from the axis outwards
    empty = np.flatnonzero(~np.isfinite(surface))
    end = int(empty[0]) if len(empty) else n_bins
    lo, hi = s.fit_band
    flank = ((surface >= lo * height) & (surface <= hi * height) & (centres >= s.fit_min_radius)
             & (np.arange(n_bins) < end))
    n_fit = int(flank.sum())
    out: dict[str, Any] = dict(heap_height=height, runout_radius=runout, n_fit=n_fit,
                               fit_r2=float("nan"), fit_rmse=float("nan"))
    if height >= s.min_heap_height and n_fit >= s.fit_min_points:
        slope, intercept = np.polyfit(centres[flank], surface[flank], 1)
        resid = surface[flank] - (slope * centres[flank] + intercept)
        ss_tot = float(((surface[flank] - surface[flank].mean()) ** 2).sum())
        out.update(fit_r2=1.0 - float((resid ** 2).sum()) / ss_tot if ss_tot > 0 else float("nan"),
                   fit_rmse=float(np.sqrt((resid ** 2).mean())))
        if slope < 0:
            out.update(repose_deg=math.degrees(math.atan(-slope)), heap_formed=True)
            return out
    # no heap (a spread layer): aspect angle of the pile, atan(height / runout), small and finite
    aspect = math.degrees(math.atan(height / runout)) if runout > 0 else 0.0
    out.update(repose_deg=aspect, heap_formed=False)
    return out


def analyze_heap(material: Material, s: HeapSettings, workdir: Path, run: SolverRun) -> HeapResult:
    what = f"heap test in {workdir}"
    dump = _read_dump(workdir / "heap_final.txt", what)
    info = read_info(workdir / "info.txt", what)
    n_fill = int(info["nfill"])
    if n_fill != s.n_particles:
        raise SolverError(f"{what}: only {n_fill} of {s.n_particles} particles were inserted into the tube "
                          f"(see {workdir}/log.liggghts)")
    _, x, y, z, radius, vx, vy, vz = dump.T
    fit = fit_heap(x, y, z + radius, material.diameter, s)
    return HeapResult(
        repose_deg=float(fit["repose_deg"]), heap_formed=bool(fit["heap_formed"]),
        heap_height=float(fit["heap_height"]), runout_radius=float(fit["runout_radius"]),
        fit_r2=float(fit["fit_r2"]), fit_rmse=float(fit["fit_rmse"]), n_fit=int(fit["n_fit"]),
        n_particles=len(dump), n_lost=int(s.n_particles - len(dump)),
        max_speed=float(np.sqrt(vx ** 2 + vy ** 2 + vz ** 2).max()) if len(dump) else 0.0,
        cpu_s=run.cpu_s, wall_s=run.wall_s)


def run_heap_test(material: Material, settings: HeapSettings, workdir: Path | str,
                  timeout_s: float | None = None) -> HeapResult:
    """Run one heap test in `workdir` (created; files overwritten) and return the angle of repose.

    Raises ConfigError for invalid settings and SolverError (naming the folder) when the run fails."""
    settings.validate("heap")
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    for stale in ("info.txt", "heap_final.txt"):
        (workdir / stale).unlink(missing_ok=True)
    write_tube(material, settings, workdir / "tube.stl")
    run = run_input(heap_input(material, settings), workdir, "in.heap", "LIGGGHTS heap test", timeout_s)
    return analyze_heap(material, settings, workdir, run)
