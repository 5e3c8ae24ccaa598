"""The granular material shared by the hopper run and its characterization tests (shear, heap).

One dataclass, one LIGGGHTS snippet: the hopper, shear box and heap inputs all define the material the
same way, so theta and the repose angle characterize exactly the material that drains in the hopper.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from neuraldem.config import checks
from neuraldem.errors import ConfigError

ROLLING_MODELS = ("epsd2", "cdt", "epsd", "epsd3")


@dataclass(frozen=True)
class Material:
    """Monodisperse spheres with Hertz contacts, tangential history and rolling friction."""

    diameter: float = 0.01  # [m]
    density: float = 2500.0  # [kg/m^3]
    youngs_modulus: float = 5.0e6  # [Pa]; < 5e6 needs `soft_particles yes` (always set by our inputs)
    poisson_ratio: float = 0.3
    restitution: float = 0.5
    mu_s: float = 0.5  # sliding friction (particle-particle and particle-wall)
    mu_r: float = 0.1  # rolling friction coefficient
    rolling_model: str = "epsd2"
    dt: float = 1.0e-4  # DEM timestep [s]

    @classmethod
    def from_config(cls, cfg: Any, key: str, **overrides: float) -> Material:
        """Build from a config mapping (e.g. `data.scene.material`), validating every value."""
        values = dict(cfg)
        values.update(overrides)
        unknown = sorted(set(values) - set(cls.__dataclass_fields__))
        if unknown:
            raise ConfigError(f"unknown key(s) {unknown} in {key}; known: {list(cls.__dataclass_fields__)}")
        m = cls(**values)
        m.validate(key)
        return m

    def validate(self, key: str) -> None:
        checks.positive(f"{key}.diameter", self.diameter)
        checks.positive(f"{key}.density", self.density)
        checks.positive(f"{key}.youngs_modulus", self.youngs_modulus)
        checks.number(f"{key}.poisson_ratio", self.poisson_ratio, lo=0.0, hi=0.5, hi_open=True)
        checks.number(f"{key}.restitution", self.restitution, lo=0.0, hi=1.0, lo_open=True)
        checks.number(f"{key}.mu_s", self.mu_s, lo=0.0, hi=2.0)
        checks.number(f"{key}.mu_r", self.mu_r, lo=0.0, hi=1.0)
        checks.one_of(f"{key}.rolling_model", self.rolling_model, ROLLING_MODELS)
        checks.positive(f"{key}.dt", self.dt)

    @property
    def radius(self) -> float:
        return 0.5 * self.diameter

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def liggghts_definition(self, n_types: int = 2) -> str:
        """Material properties, contact model and timestep for `n_types` atom types (particles, walls)."""
        def per_type(v: float) -> str:
            return " ".join([repr(v)] * n_types)

        def per_pair(v: float) -> str:
            return f"{n_types} " + " ".join([repr(v)] * n_types * n_types)

        model = f"hertz tangential history rolling_friction {self.rolling_model}"
        return "\n".join([
            f"fix m1 all property/global youngsModulus peratomtype {per_type(self.youngs_modulus)}",
            f"fix m2 all property/global poissonsRatio peratomtype {per_type(self.poisson_ratio)}",
            f"fix m3 all property/global coefficientRestitution peratomtypepair {per_pair(self.restitution)}",
            f"fix m4 all property/global coefficientFriction peratomtypepair {per_pair(self.mu_s)}",
            f"fix m5 all property/global coefficientRollingFriction peratomtypepair {per_pair(self.mu_r)}",
            f"pair_style gran model {model}",
            "pair_coeff * *",
            f"timestep {self.dt!r}",
        ]) + "\n"

    @property
    def wall_model(self) -> str:
        """The `model ...` arguments of a `fix wall/gran` with the same contact law."""
        return f"model hertz tangential history rolling_friction {self.rolling_model}"
