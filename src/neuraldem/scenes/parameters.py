"""A scene's parameters, declared once: name, unit, what the solver can run at all, and what it means.

The table is the one source for what a user may ask of a scene: datagen checks its sampling ranges against
it, `predict` and `scan` parse their `name=value` arguments with it, the explorer builds its sliders and
clamps typed values with it, and the GNS reads its conditioning names from it. A value the solver cannot
run is refused; a value it can run but a model never saw is answered with a warning (`range_warnings`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from neuraldem.errors import ConfigError


@dataclass(frozen=True)
class Parameter:
    name: str
    unit: str  # "" for dimensionless
    low: float  # what the solver can run at all (inclusive)
    high: float
    meaning: str

    @property
    def limits(self) -> tuple[float, float]:
        return (self.low, self.high)

    def label(self) -> str:
        return f"{self.name} [{self.unit}]" if self.unit else self.name


@dataclass(frozen=True)
class ParameterTable:
    """The parameters a scene is sampled over and a model is conditioned on, in their canonical order."""

    parameters: tuple[Parameter, ...]

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.parameters]

    def __getitem__(self, name: str) -> Parameter:
        for p in self.parameters:
            if p.name == name:
                return p
        raise ConfigError(f"unknown parameter {name!r}", f"the parameters are {', '.join(self.names)}")

    def __contains__(self, name: object) -> bool:
        return name in self.names

    def limits(self, name: str) -> tuple[float, float]:
        """What the solver can run for one parameter; a name the table does not hold (a measured scalar such as
        the shear angle theta) is unlimited."""
        return self[name].limits if name in self else (-math.inf, math.inf)

    def check(self, name: str, values: Iterable[float]) -> None:
        """Values the solver cannot run at all are refused naming the parameter and its limits."""
        values = list(values)
        lo, hi = self.limits(name)
        if min(values) < lo or max(values) > hi:
            shown = f"={values[0]:g}" if len(values) == 1 else f" spans {min(values):g} .. {max(values):g},"
            raise ConfigError(f"parameter {name}{shown} is outside what the solver can run ({lo:g} .. {hi:g})")

    def check_range(self, key: str, bounds: tuple[float, float]) -> None:
        """A sampling range (datagen) inside the solver's limits, low < high; the error names the config key."""
        lo, hi = (float(b) for b in bounds)
        plo, phi = self.limits(key.rsplit(".", 1)[-1])
        if not (plo <= lo < hi <= phi):
            raise ConfigError(f"config value {key}=[{lo:g}, {hi:g}] is invalid: need {plo:g} <= low < high <= {phi:g}")

    def table_markdown(self) -> str:
        """The table as docs show it (`docs/your-own-scene.md` quotes each scene's)."""
        rows = ["| parameter | unit | solver limits | meaning |", "|---|---|---|---|"]
        rows += [f"| {p.name} | {p.unit or '-'} | {p.low:g} .. {p.high:g} | {p.meaning} |" for p in self.parameters]
        return "\n".join(rows)


@dataclass(frozen=True)
class SceneKey:
    """One key of a scene file (dotted, as in `conf/data/<scene>.yaml`): its unit, what it means and what changing
    it costs. A scene's table (`Scene.scene_keys`) comments the files `neuraldem scene new` writes and is the
    reference table of docs/your-own-scene.md."""

    key: str
    unit: str  # "-" for dimensionless
    meaning: str
    cost: str


def load_scene_keys(path: Path) -> tuple[SceneKey, ...]:
    """A scene's key table from its YAML file (a list of {key, unit, meaning, cost}: data, kept out of code)."""
    import yaml

    return tuple(SceneKey(**row) for row in yaml.safe_load(Path(path).read_text()))


def scene_key_markdown(keys: Iterable[SceneKey]) -> str:
    """The reference table of a scene's keys as docs/your-own-scene.md shows it."""
    rows = ["| key | unit | meaning | cost |", "|---|---|---|---|"]
    rows += [f"| `{k.key}` | {k.unit} | {k.meaning} | {k.cost} |" for k in keys]
    return "\n".join(rows)


def named_values(items: Mapping[str, str], names: list[str], scene: str) -> dict[str, str]:
    """`name=text` arguments of a what-if: the model's inputs only, and every one of them."""
    for key in items:
        if key not in names:
            raise ConfigError(f"unknown {scene} parameter {key!r}", f"the parameters are {', '.join(names)}")
    missing = [n for n in names if n not in items]
    if missing:
        raise ConfigError(f"missing {scene} parameter(s) {', '.join(missing)}",
                          f"give all of {' '.join(f'{n}=VALUE' for n in names)}")
    return {n: items[n] for n in names}


def parse_point(items: Mapping[str, str], names: list[str], scene: str, table: ParameterTable) -> dict[str, float]:
    """`name=value` arguments as {name: value} in the model's input order, each finite and runnable."""
    out: dict[str, float] = {}
    for key, text in named_values(items, names, scene).items():
        try:
            out[key] = float(text)
        except ValueError:
            raise ConfigError(f"parameter {key}={text!r} is not a number") from None
        if not math.isfinite(out[key]):
            raise ConfigError(f"parameter {key}={text} is not a finite number")
        table.check(key, [out[key]])
    return out


def asked_note(name: str, trained: tuple[float, float] | list[float] | None,
               asked: Mapping[str, list[float]] | None) -> str:
    """`, asked 0.2 .. 0.8` where the runs covered less of a parameter than datagen was asked for (else '')."""
    if not asked or name not in asked or trained is None:
        return ""
    lo, hi = (float(v) for v in asked[name])
    if all(abs(a - float(b)) <= 1e-9 * max(1.0, abs(a)) for a, b in zip((lo, hi), trained, strict=True)):
        return ""
    return f"; datagen was asked for {lo:.4g} .. {hi:.4g}, the runs cover less (more runs fill it)"


def range_warnings(extrapolation: Mapping[str, list[float]], who: str,
                   asked: Mapping[str, list[float]] | None = None) -> list[str]:
    """One warning per input outside the range a model was trained on (`{name: [value, low, high]}`), naming
    the range datagen was asked for where its runs covered less (`asked`: meta.json's `asked_range`)."""
    return [f"warning: {who}: {k}={v[0]:.4g} is outside the trained range {v[1]:.4g} .. {v[2]:.4g}"
            f"{asked_note(k, v[1:3], asked)}: an extrapolation, trust it less"
            for k, v in extrapolation.items() if k != "query_points_outside_box"]


def ranges_line(meta: Mapping[str, object]) -> str:
    """What a released model was trained on, per input: the range its runs cover and, where datagen was asked
    for more, that range (the explorer shows it under the sliders)."""
    trained = meta.get("trained_range") or {}
    asked = meta.get("asked_range") or {}
    parts = []
    for name, (lo, hi) in trained.items():  # type: ignore[union-attr]
        part = f"{name} {lo:.4g} .. {hi:.4g}"
        if name in asked and asked_note(name, (lo, hi), asked):  # type: ignore[arg-type]
            a = asked[name]  # type: ignore[index]
            part += f" (asked {float(a[0]):.4g} .. {float(a[1]):.4g})"
        parts.append(part)
    return "trained on runs covering " + ", ".join(parts) if parts else ""
