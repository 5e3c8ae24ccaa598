"""Periodic plane-shear test at constant normal stress: the internal friction angle theta of a material.

The cell is a box periodic in x and y. Spheres of the material are poured onto a floor and settled; then

* the particles of the lowest `bottom_slab` diameters are frozen: a rough, immobile base;
* the particles within `top_slab` diameters of the bed top form a rigid lid that does not rotate; it is
  driven at a constant velocity in x and carries a dead load sigma_n * A in z (it moves freely in z, so the
  packing can dilate);
* gravity and the floor are switched off, so the stress in the sheared layer between the slabs is uniform.

After a consolidation at sigma_n the lid is sheared at the velocity that gives the nominal inertial number
I = gdot * d / sqrt(sigma_n / rho) (quasi-static for I <~ 0.01). The contact forces of the layer on both
slabs are averaged over the steady part of the shear (strain >= `average_from`) and

    theta = atan(tau / sigma_n),   tau = <F_x> / A,   sigma_n = <F_z> / A

(the Jenike / ring-shear definition on the horizontal plane; top and bottom slab are averaged). The
Mohr-Coulomb angle asin((s1 - s3) / (s1 + s3)) of the full bulk stress tensor is reported as a diagnostic.

All numbers of the LIGGGHTS input come from `Material` and `ShearSettings`; the input is written into the
run folder (`in.shear`) next to the solver log, so every run can be repeated by hand.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any, Self

import numpy as np

from neuraldem.config import checks
from neuraldem.errors import ConfigError, SolverError
from neuraldem.sim.liggghts import preamble
from neuraldem.sim.material import Material
from neuraldem.sim.runner import SolverRun, require_success, run_liggghts
from neuraldem.sim.seeds import is_prime

# Seeds of the particle template and distribution fixes. LIGGGHTS wants every seed of an input to be a
# distinct prime > 10000; the packing seed of each test is a setting and must differ from these.
TEMPLATE_SEED = 10000019
DISTRIBUTION_SEED = 20000003
# Solid fraction of the loose random packing that `insert/pack` creates before the pour.
INSERT_FRACTION = 0.25
GRAVITY = 9.81
PRESETS = ("small", "tiny")
# at most this fraction of the particles may escape through the slabs during a shear test
MAX_LOST_FRACTION = 0.01


# ----------------------------------------------------------------------------------------------------------
# helpers shared with the heap test
# ----------------------------------------------------------------------------------------------------------
def check_seed(key: str, value: Any) -> int:
    """A packing seed: a prime > 10000 that differs from the template seeds (LIGGGHTS requirement)."""
    checks.positive_int(key, value)
    if value <= 10000 or not is_prime(value) or value in (TEMPLATE_SEED, DISTRIBUTION_SEED):
        raise ConfigError(
            f"config value {key}={value!r} is invalid: LIGGGHTS needs a prime > 10000 that differs from "
            f"{TEMPLATE_SEED} and {DISTRIBUTION_SEED} (override it, e.g. {key}=49979687)")
    return value


def settings_from_config(cls: type, cfg: Any, key: str) -> Any:
    """Build a settings dataclass from a mapping: optional `preset` (small | tiny) plus field overrides."""
    if cfg is None:
        cfg = {}
    if not isinstance(cfg, Mapping) and not hasattr(cfg, "items"):
        raise ConfigError(f"config value {key} must be a mapping of settings, got {type(cfg).__name__}")
    values = {str(k): v for k, v in cfg.items()}
    preset = values.pop("preset", "small")
    checks.one_of(f"{key}.preset", preset, PRESETS)
    names = [f.name for f in fields(cls)]
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise ConfigError(f"unknown key(s) {unknown} in {key}; known: ['preset'] + {names}")
    base = cls.tiny() if preset == "tiny" else cls()
    settings = replace(base, **values)
    settings.validate(key)
    return settings


def run_input(text: str, workdir: Path, input_name: str, what: str, timeout_s: float | None) -> SolverRun:
    """Write `text` to workdir/input_name, run LIGGGHTS there; SolverError (naming the folder) on failure."""
    workdir.mkdir(parents=True, exist_ok=True)
    (workdir / input_name).write_text(text)
    try:
        run = run_liggghts(workdir, input_name, timeout_s=timeout_s)
    except SolverError as err:
        raise SolverError(f"{what} could not start in {workdir}: {err}") from err
    require_success(run, what)
    return run


class PresetSettings:
    """Base of the test settings (frozen dataclasses with `tiny()` and `validate(key)`): a preset, `small` (the
    defaults) or `tiny`, plus field overrides from config, so both tests read their config the same way."""

    @classmethod
    def from_config(cls, cfg: Any, key: str) -> Self:
        """From a mapping such as `data.characterization.shear`: `preset` (small | tiny) + overrides."""
        return settings_from_config(cls, cfg, key)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)  # type: ignore[call-overload]  # every subclass is a dataclass


def box_input(material: Material, boundary: str, lo: tuple[float, float, float], hi: tuple[float, float, float],
              n_types: int) -> str:
    """The LIGGGHTS lines from the preamble to the material: the box [lo, hi] with `n_types` atom types and a
    neighbour skin of 0.3 d, the same in every test so the tests differ only where their physics does."""
    d = material.diameter
    return f"""\
{preamble(boundary)}
region domain block {lo[0]!r} {hi[0]!r} {lo[1]!r} {hi[1]!r} {lo[2]!r} {hi[2]!r} units box
create_box {n_types} domain
neighbor {0.3 * d!r} bin
neigh_modify delay 0
{material.liggghts_definition(n_types=n_types)}"""


def pour_input(material: Material, seed: int, n_particles: int) -> str:
    """The LIGGGHTS lines that pour `n_particles` spheres into region `fillreg` (a loose insert/pack, overlap-
    checked, with the fixed template seeds) and integrate them: one packing procedure for every test."""
    return f"""\
fix tmpl all particletemplate/sphere {TEMPLATE_SEED} atom_type 1 density constant {material.density!r} \
radius constant {material.radius!r}
fix dist all particledistribution/discrete {DISTRIBUTION_SEED} 1 tmpl 1.0
fix fill all insert/pack seed {seed} distributiontemplate dist vel constant 0.0 0.0 -0.5 \
insert_every once overlapcheck yes all_in yes particles_in_region {n_particles} region fillreg ntry_mc 20000
fix integ all nve/sphere
thermo_style custom step time atoms ke cpu"""


def missing_output(path: Path, what: str) -> SolverError:
    return SolverError(f"{what}: the solver finished without writing {path.name} "
                       f"(see {path.parent}/log.liggghts)")


def read_info(path: Path, what: str) -> dict[str, float]:
    """`name value` pairs that an input printed into a file (geometry and counts known only at run time)."""
    if not path.exists():
        raise missing_output(path, what)
    tokens = path.read_text().split()
    try:
        return {tokens[i]: float(tokens[i + 1]) for i in range(0, len(tokens) - 1, 2)}
    except ValueError as err:
        raise SolverError(f"{what}: cannot read {path}: {err}") from err


# ----------------------------------------------------------------------------------------------------------
# settings and result
# ----------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ShearSettings(PresetSettings):
    """Shear-cell settings. The defaults are the "small" production preset for the 10 mm hopper material
    (~20-35 CPU-s per test); `ShearSettings.tiny()` is a few CPU-s for tests (noisier, ~1-2 deg)."""

    box_size: float = 10.0  # periodic box edge in x and y [particle diameters]
    n_particles: int = 1500  # all particles, slabs included
    normal_stress: float = 3000.0  # dead load on the top slab [Pa]
    inertial_number: float = 0.01  # nominal I = gdot * d / sqrt(sigma_n / rho)
    strain: float = 4.0  # total shear strain V * t / H0
    average_from: float = 1.0  # average the slab forces over strain [average_from, strain]
    settle_time: float = 0.4  # pour + settle under gravity [s]
    consolidation_time: float = 0.15  # under sigma_n before the shear [s]
    bottom_slab: float = 1.5  # frozen base: particle centres below this height [d]
    top_slab: float = 1.5  # rigid lid: centres within this distance of the bed top [d]
    n_blocks: int = 6  # blocks of the averaging window for the statistical error
    average_steps: int = 100  # the force time series is written as averages over this many steps
    seed: int = 49979687  # packing seed (prime > 10000)

    @classmethod
    def tiny(cls) -> ShearSettings:
        """A few CPU seconds: 7 d box, 500 particles, strain 1.5 at I = 0.02. Noisy (~1-2 deg)."""
        return cls(box_size=7.0, n_particles=500, inertial_number=0.02, strain=1.5, average_from=0.5,
                   settle_time=0.25, consolidation_time=0.05, n_blocks=4)

    def validate(self, key: str = "shear") -> None:
        checks.number(f"{key}.box_size", self.box_size, lo=4.0)
        checks.positive_int(f"{key}.n_particles", self.n_particles)
        checks.positive(f"{key}.normal_stress", self.normal_stress)
        checks.number(f"{key}.inertial_number", self.inertial_number, lo=0.0, hi=0.2, lo_open=True)
        checks.positive(f"{key}.strain", self.strain)
        checks.number(f"{key}.average_from", self.average_from, lo=0.0, hi=self.strain, hi_open=True)
        checks.positive(f"{key}.settle_time", self.settle_time)
        checks.number(f"{key}.consolidation_time", self.consolidation_time, lo=0.0)
        checks.positive(f"{key}.bottom_slab", self.bottom_slab)
        checks.positive(f"{key}.top_slab", self.top_slab)
        checks.positive_int(f"{key}.n_blocks", self.n_blocks)
        checks.number(f"{key}.n_blocks", self.n_blocks, lo=2)
        checks.positive_int(f"{key}.average_steps", self.average_steps)
        if self.average_steps % 10:
            raise ConfigError(f"config value {key}.average_steps={self.average_steps!r} is invalid: must be "
                              f"a multiple of 10 (override it, e.g. {key}.average_steps=100)")
        check_seed(f"{key}.seed", self.seed)
        # the sheared layer between the slabs must be a few diameters thick to shear in the bulk
        layer = self.n_particles / (0.6 * self.box_size ** 2 * 6.0 / math.pi)  # settled height [d]
        gap = layer - self.bottom_slab - self.top_slab
        if gap < 3.0:
            raise ConfigError(
                f"config value {key}.n_particles={self.n_particles!r} is invalid: with {key}.box_size="
                f"{self.box_size} the sheared layer between the slabs would be only ~{gap:.1f} particle "
                f"diameters thick (needs >= 3); raise {key}.n_particles")


@dataclass(frozen=True)
class ShearResult:
    theta_deg: float  # atan(tau / sigma_n) at steady flow, mean of top and bottom slab
    theta_err_deg: float  # standard error from `n_blocks` blocks of the averaging window
    theta_top_deg: float  # from the top slab alone (check: agrees with the bottom one)
    theta_bottom_deg: float
    mohr_coulomb_deg: float  # asin((s1 - s3) / (s1 + s3)) of the bulk stress tensor (diagnostic)
    normal_stress: float  # applied sigma_n [Pa]
    normal_stress_measured: float  # <F_z> / A on the top slab [Pa]
    shear_stress: float  # tau = sigma_n * tan(theta) with the measured sigma_n [Pa]
    solid_fraction: float  # of the sheared layer, averaged over the window
    dilation: float  # gap growth during the shear [d]
    layer_height: float  # gap between the slabs when the shear starts [d]
    shear_velocity: float  # of the top slab [m/s]
    n_particles: int
    n_sheared: int  # particles between the slabs
    n_lost: int  # escaped through a slab and left the box (<= 1 % tolerated)
    cpu_s: float
    wall_s: float

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


# ----------------------------------------------------------------------------------------------------------
# LIGGGHTS input
# ----------------------------------------------------------------------------------------------------------
def shear_input(material: Material, s: ShearSettings) -> str:
    """The LIGGGHTS input of one shear test (all values from the material and the settings)."""
    d = material.diameter
    edge = s.box_size * d
    area = edge * edge
    particle_volume = math.pi / 6.0 * d ** 3
    fill_height = s.n_particles * particle_volume / (INSERT_FRACTION * area) + d
    n_settle = max(1, round(s.settle_time / material.dt))
    n_cons = max(1, round(s.consolidation_time / material.dt))
    gdot = s.inertial_number * math.sqrt(s.normal_stress / material.density) / d
    n_shear = math.ceil(s.strain / gdot / material.dt / s.average_steps) * s.average_steps
    return f"""\
# neuraldem periodic shear cell: theta = atan(tau / sigma_n) (written by neuraldem.sim.shear)
{box_input(material, "p p f", (0, 0, -0.5 * d), (edge, edge, fill_height + 2 * d), n_types=1)}
# ---- 1. pour onto a flat floor and settle under gravity
fix grav all gravity {GRAVITY} vector 0.0 0.0 -1.0
fix floor all wall/gran {material.wall_model} primitive type 1 zplane 0.0
region fillreg block 0 {edge!r} 0 {edge!r} 0 {fill_height!r} units box
{pour_input(material, s.seed, s.n_particles)}
thermo 1000
thermo_modify norm no
run {n_settle}
unfix fill
variable nnow equal count(all)
variable ninserted equal ${{nnow}}

# ---- 2. slabs: frozen base, rigid non-rotating lid under a dead load; no gravity, no floor
# top of the bed: the highest centre, or twice the mean height if lower (a particle perched on the surface
# must not thin the lid); min(a,b) = (a + b - |a - b|) / 2
variable zmaxc equal bound(all,zmax)
variable zmean equal 2.0*xcm(all,z)
variable zhigh equal 0.5*(v_zmaxc+v_zmean-abs(v_zmaxc-v_zmean))
variable zlid equal ${{zhigh}}-{s.top_slab * d!r}
region lidreg block EDGE EDGE EDGE EDGE ${{zlid}} EDGE units box
region basereg block EDGE EDGE EDGE EDGE EDGE {s.bottom_slab * d!r} units box
group lid region lidreg
group base region basereg
group slabs union lid base
group layer subtract all slabs
variable nlid equal count(lid)
variable load equal -{s.normal_stress * area!r}/${{nlid}}
unfix grav
unfix floor
unfix integ
velocity base set 0.0 0.0 0.0
velocity lid set 0.0 0.0 0.0
set group base omegax 0.0 omegay 0.0 omegaz 0.0
set group lid omegax 0.0 omegay 0.0 omegaz 0.0
# global vectors of freeze/setforce/aveforce = the contact force on the group before it is overwritten
fix basefix base freeze
fix integ layer nve/sphere
fix lidmove lid nve
fix lidxy lid setforce 0.0 0.0 NULL
fix lidz lid aveforce NULL NULL ${{load}}
variable gap equal bound(lid,zmin)-bound(base,zmax)
thermo_style custom step time atoms ke v_gap f_lidxy[1] f_lidz[3] cpu
run {n_cons}

# ---- 3. shear the lid at constant velocity in x
variable gap0 equal ${{gap}}
variable vlid equal {gdot!r}*${{gap0}}
variable stepnow equal step
variable step0 equal ${{stepnow}}
velocity lid set ${{vlid}} 0.0 NULL
fix forces all ave/time 1 {s.average_steps} {s.average_steps} f_lidxy[1] f_lidz[3] f_basefix[1] f_basefix[3] \
v_gap file forces.txt
compute sat layer stress/atom pair
compute ssum layer reduce sum c_sat[1] c_sat[2] c_sat[3] c_sat[5]
fix stress all ave/time 10 {s.average_steps // 10} {s.average_steps} c_ssum[1] c_ssum[2] c_ssum[3] \
c_ssum[4] file stress.txt
run {n_shear}
variable nall equal count(all)
variable nlayer equal count(layer)
print "ninserted ${{ninserted}} natoms ${{nall}} nlayer ${{nlayer}} nlid ${{nlid}} gap0 ${{gap0}} \
vlid ${{vlid}} step0 ${{step0}} nshear {n_shear}" file info.txt
"""


# ----------------------------------------------------------------------------------------------------------
# run + analysis
# ----------------------------------------------------------------------------------------------------------
def _load_table(path: Path, n_cols: int, what: str) -> np.ndarray:
    if not path.exists():
        raise missing_output(path, what)
    data = np.loadtxt(path, comments="#", ndmin=2)
    if data.shape[1] != n_cols or len(data) == 0:
        raise SolverError(f"{what}: {path} has shape {data.shape}, expected rows of {n_cols} columns")
    return data


def analyze_shear(material: Material, s: ShearSettings, workdir: Path, run: SolverRun) -> ShearResult:
    """Read forces.txt / stress.txt / info.txt of a finished run into a ShearResult."""
    what = f"shear test in {workdir}"
    info = read_info(workdir / "info.txt", what)
    if int(info["ninserted"]) != s.n_particles:
        raise SolverError(f"{what}: only {int(info['ninserted'])} of {s.n_particles} particles were inserted "
                          f"(see {workdir}/log.liggghts)")
    # a layer particle may slip through a gap of the lid (loose, high-friction packings) and leave the box;
    # a few of them do not change the stress ratio, many mean the slabs are too thin
    n_lost = s.n_particles - int(info["natoms"])
    if n_lost > max(1, MAX_LOST_FRACTION * s.n_particles):
        raise SolverError(f"{what}: {n_lost} of {s.n_particles} particles escaped through the slabs; "
                          f"make shear.top_slab / shear.bottom_slab thicker (see {workdir}/log.liggghts)")
    lid_expected = s.top_slab * s.box_size ** 2 * 0.55 * 6.0 / math.pi  # a full lid at solid fraction 0.55
    if info["nlid"] < 0.5 * lid_expected:
        raise SolverError(f"{what}: the top slab got only {int(info['nlid'])} particles (a full one has "
                          f"~{lid_expected:.0f}); the bed had not settled: raise the settle_time")
    d = material.diameter
    area = (s.box_size * d) ** 2
    forces = _load_table(workdir / "forces.txt", 6, what)
    step, fx_lid, fz_lid, fx_base, fz_base, gap = forces.T
    gap0, vlid = info["gap0"], info["vlid"]
    strain = (step - info["step0"]) * material.dt * vlid / gap0
    window = np.flatnonzero(strain > s.average_from + 1e-9)
    if len(window) < s.n_blocks:
        raise SolverError(f"{what}: only {len(window)} force samples in the averaging window")

    def ratio(ix: np.ndarray) -> tuple[float, float]:
        # lid: the layer pushes it up and drags it back; base: pushed down, dragged forward
        return float(-fx_lid[ix].mean() / fz_lid[ix].mean()), float(-fx_base[ix].mean() / fz_base[ix].mean())

    mu_lid, mu_base = ratio(window)
    mu = 0.5 * (mu_lid + mu_base)
    blocks = [0.5 * sum(ratio(ix)) for ix in np.array_split(window, s.n_blocks)]
    mu_err = float(np.std(blocks, ddof=1) / math.sqrt(len(blocks)))
    sigma_meas = float(fz_lid[window].mean() / area)

    stress = _load_table(workdir / "stress.txt", 5, what)
    sel = np.isin(stress[:, 0], step[window])
    # sums of per-atom stress * volume (compression negative): the bulk stress up to a common factor
    sxx, syy, szz, sxz = (-float(stress[sel, k].mean()) for k in (1, 2, 3, 4))
    eig = np.linalg.eigvalsh(np.array([[sxx, 0.0, sxz], [0.0, syy, 0.0], [sxz, 0.0, szz]]))
    mohr_coulomb = math.degrees(math.asin((eig[-1] - eig[0]) / (eig[-1] + eig[0])))

    mean_gap = float(gap[window].mean())
    n_layer = int(info["nlayer"])
    solid_fraction = n_layer * math.pi / 6.0 * d ** 3 / (area * mean_gap)
    theta = math.degrees(math.atan(mu))
    if not math.isfinite(theta):
        raise SolverError(f"{what}: the measured stress ratio is not finite (see {workdir}/log.liggghts)")
    return ShearResult(
        theta_deg=theta,
        theta_err_deg=math.degrees(mu_err / (1.0 + mu * mu)),
        theta_top_deg=math.degrees(math.atan(mu_lid)),
        theta_bottom_deg=math.degrees(math.atan(mu_base)),
        mohr_coulomb_deg=mohr_coulomb,
        normal_stress=float(s.normal_stress),
        normal_stress_measured=sigma_meas,
        shear_stress=sigma_meas * mu,
        solid_fraction=solid_fraction,
        dilation=(mean_gap - gap0) / d,
        layer_height=gap0 / d,
        shear_velocity=vlid,
        n_particles=int(info["natoms"]),
        n_sheared=n_layer,
        n_lost=n_lost,
        cpu_s=run.cpu_s,
        wall_s=run.wall_s,
    )


def run_shear_test(material: Material, settings: ShearSettings, workdir: Path | str,
                   timeout_s: float | None = None) -> ShearResult:
    """Run one shear test in `workdir` (created; files overwritten) and return theta and diagnostics.

    Raises ConfigError for invalid settings and SolverError (naming the folder) when the run fails."""
    settings.validate("shear")
    workdir = Path(workdir)
    what = "LIGGGHTS shear test"
    for stale in ("info.txt", "forces.txt", "stress.txt"):
        (workdir / stale).unlink(missing_ok=True)
    run = run_input(shear_input(material, settings), workdir, "in.shear", what, timeout_s)
    return analyze_shear(material, settings, workdir, run)


# ----------------------------------------------------------------------------------------------------------
# yield locus (several normal stresses): shows that the material is cohesionless
# ----------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class YieldLocus:
    angle_deg: float  # slope of tau(sigma_n)
    cohesion: float  # intercept tau(0) [Pa]
    unconfined_yield_strength: float  # sigma_c = 2 c cos(phi) / (1 - sin(phi)) [Pa], 0 for c <= 0
    normal_stresses: tuple[float, ...]
    shear_stresses: tuple[float, ...]


def fit_yield_locus(results: Sequence[ShearResult]) -> YieldLocus:
    """Straight line tau = c + sigma_n tan(phi) through the steady-state points of several shear tests.

    A cohesionless material has c ~ 0, hence an unconfined yield strength sigma_c ~ 0 and an undefined
    (infinite) flow function coefficient ffc = sigma_1 / sigma_c."""
    sig = np.array([r.normal_stress_measured for r in results])
    tau = np.array([r.shear_stress for r in results])
    if len(results) < 2 or np.ptp(sig) <= 0:
        raise ValueError("fit_yield_locus needs shear tests at two or more different normal stresses")
    slope, intercept = np.polyfit(sig, tau, 1)
    phi = math.atan(slope)
    sigma_c = max(0.0, 2.0 * intercept * math.cos(phi) / (1.0 - math.sin(phi)))
    return YieldLocus(math.degrees(phi), float(intercept), sigma_c,
                      tuple(float(x) for x in sig), tuple(float(x) for x in tau))
