"""Scenes by kind: the one place that says what a hopper, a refilling hopper or a fluidized bed is made of.

Datagen, training, evaluation and the command line look a scene up here by its `kind` (the dataset's
`data.kind`, a checkpoint's metadata) instead of each keeping an if-chain. A new scene (say a rotating drum)
adds a package `neuraldem.scenes.<kind>` that defines `SCENE` and one line in `KINDS`
(docs/adding-a-scene.md lists the files it writes). Scene modules import their heavy parts (solvers, torch
models) inside the functions, so looking a scene up costs nothing.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from neuraldem.errors import ConfigError

if TYPE_CHECKING:
    from omegaconf import DictConfig

    from neuraldem.datagen.driver import Pipeline

KINDS = ("hopper", "hopper_refill", "fluidized_bed")


@dataclass(frozen=True)
class Scene:
    """What the generic commands need from a scene."""

    kind: str
    description: str
    experiment: str  # `neuraldem train experiment=...` that trains a model of this scene (said in errors)
    pipeline: Callable[[DictConfig], Pipeline]  # datagen: the solver pipeline for a `data` config
    evaluate: Callable[[DictConfig], None]  # `neuraldem evaluate ckpt=...` of a checkpoint of this kind
    evaluate_run: Callable[[DictConfig, Path], dict[str, Any]]  # after training: score ckpt into <run>/evaluation


def scene(kind: object, key: str = "data.kind") -> Scene:
    """The registered scene of `kind`; an unknown kind is refused naming `key` and the known kinds."""
    if kind not in KINDS:
        raise ConfigError(f"config value {key}={kind!r} is invalid: the scenes are {', '.join(map(repr, KINDS))}")
    return importlib.import_module(f"neuraldem.scenes.{kind}").SCENE
