"""Validation of user-settable config values, with messages that name the key and the fix.

Every constructor that takes a user-facing value checks it with one of these, using the dotted config key
(e.g. ``data.batch_size``) so that the message tells the user exactly what to override.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

from neuraldem.commands import command_or_module
from neuraldem.errors import ConfigError


def _fail(key: str, value: Any, requirement: str) -> ConfigError:
    return ConfigError(f"config value {key}={value!r} is invalid: {requirement} (override it, e.g. {key}=...)")


def known_keys(key: str, values: Iterable[Any], known: Iterable[Any]) -> None:
    """Refuse keys of `values` that are not in `known` (a typo in a config group must not be ignored)."""
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ConfigError(f"unknown key(s) {unknown} in {key}; known: {sorted(known)}")


def positive_int(key: str, value: Any, *, allow_zero: bool = False) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise _fail(key, value, "must be an integer")
    if value < 0 or (value == 0 and not allow_zero):
        raise _fail(key, value, "must be >= 0" if allow_zero else "must be a positive integer")
    return value


def number(key: str, value: Any, *, lo: float | None = None, hi: float | None = None,
           lo_open: bool = False, hi_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise _fail(key, value, "must be a finite number")
    v = float(value)
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise _fail(key, value, f"must be {'>' if lo_open else '>='} {lo}")
    if hi is not None and (v > hi or (hi_open and v == hi)):
        raise _fail(key, value, f"must be {'<' if hi_open else '<='} {hi}")
    return v


def boolean(key: str, value: Any) -> bool:
    """true/false only: a typo like `=ture` or `=1` is not silently read as a truth value."""
    if not isinstance(value, bool):
        raise _fail(key, value, "must be true or false")
    return value


def positive(key: str, value: Any) -> float:
    return number(key, value, lo=0.0, lo_open=True)


def fraction(key: str, value: Any) -> float:
    return number(key, value, lo=0.0, hi=1.0)


def is_multiple(value: float, step: float) -> bool:
    """Whether `value` is a whole number of `step`s (to 1e-6 of a step): a snapshot interval of the timestep,
    a duration of the snapshot interval. The caller's message names the keys."""
    ratio = value / step
    return abs(ratio - round(ratio)) <= 1e-6


def one_of(key: str, value: Any, choices: Iterable[Any]) -> Any:
    choices = list(choices)
    if value not in choices:
        raise _fail(key, value, f"must be one of {choices}")
    return value


def interval(key: str, value: Any) -> tuple[float, float]:
    """A [lo, hi] pair with lo <= hi (parameter ranges)."""
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) != 2:
        raise _fail(key, value, "must be a pair [lo, hi]")
    lo = number(f"{key}[0]", value[0])
    hi = number(f"{key}[1]", value[1])
    if lo > hi:
        raise _fail(key, value, "needs lo <= hi")
    return lo, hi


def names(key: str, value: Any, allowed: Iterable[str] | None = None) -> list[str]:
    """A non-empty list of unique names (e.g. conditioning scalars), optionally from an allowed set."""
    if isinstance(value, str) or not isinstance(value, Sequence) or len(value) == 0:
        raise _fail(key, value, "must be a non-empty list of names")
    out = [str(v) for v in value]
    if len(set(out)) != len(out):
        raise _fail(key, value, "has duplicate names")
    if allowed is not None:
        allowed = list(allowed)
        bad = [v for v in out if v not in allowed]
        if bad:
            raise _fail(key, value, f"unknown name(s) {bad}; allowed: {allowed}")
    return out


def required(cfg: Any, command: str, examples: dict[str, str]) -> None:
    """Keys a command cannot run without (`???` in its config) name themselves and an example, not a traceback."""
    from omegaconf import OmegaConf

    for key, example in examples.items():
        if OmegaConf.is_missing(cfg, key):
            raise ConfigError(f"{key} is required: {command_or_module(f'neuraldem.{command}')} {example} ...")
