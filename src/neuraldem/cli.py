"""Shared wrapper for the Hydra entry points: user errors end in one clear line, never a traceback."""

from __future__ import annotations

import argparse
import functools
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from neuraldem.errors import ConfigError, NeuraldemError
from neuraldem.paths import config_dir

if TYPE_CHECKING:
    from omegaconf import DictConfig


def quiet_environment() -> None:
    """Defaults that make runs offline-safe and CPU-friendly; a user's own setting always wins."""
    os.environ.setdefault("WANDB_MODE", "offline")
    os.environ.setdefault("WANDB_SILENT", "true")
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def report_user_errors(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Turn a NeuraldemError into `neuraldem: error: ...` on stderr and exit status 2."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except NeuraldemError as err:
            print(f"neuraldem: error: {err}", file=sys.stderr)
            sys.exit(2)

    return wrapper


def tool_prog(module: str) -> str:
    """A tool's name in its usage line: `neuraldem report fb-table` when the `neuraldem` command runs it
    (which puts that name in argv[0]), else `python -m <module>` (e.g. `neuraldem.bench fb_speed`)."""
    return sys.argv[0] if sys.argv[0].startswith("neuraldem ") else f"python -m {module}"


def doc_parser(module: str, doc: str | None) -> argparse.ArgumentParser:
    """A tool's parser whose --help shows its whole module docstring as written (examples keep their line
    breaks)."""
    return argparse.ArgumentParser(prog=tool_prog(module), description=doc,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)


def add_trajectory_options(p: argparse.ArgumentParser, ckpt_help: str, sim_help: str) -> None:
    """`--ckpt`, `--dataset`, `--sim`: one trajectory of a checkpoint's dataset, found from the checkpoint by
    default, as every tool that times one checkpoint asks for it."""
    p.add_argument("--ckpt", type=Path, required=True, help=ckpt_help)
    p.add_argument("--dataset", type=Path, default=None,
                   help="dataset dir of the checkpoint's scene (default: <data dir>/datasets/<its data name>)")
    p.add_argument("--sim", default=None, help=sim_help)


def split_kind_factor(text: str) -> tuple[str, float]:
    """A `KIND:FACTOR` command-line value as (kind, factor); the factor is NaN when it is not a number, so a
    caller rejects it with its own range check and message."""
    kind, _, value = text.partition(":")
    try:
        factor = float(value)
    except ValueError:
        factor = float("nan")
    return kind, factor


def parse_assignments(items: list[str], flag: str, example: str) -> dict[str, float]:
    """`NAME=NUMBER` command-line values (e.g. repeated `--param alpha=30`) as a dict."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        try:
            out[key] = float(value)
        except ValueError:
            sep = ""
        if not sep or not key:
            raise ConfigError(f"{flag} {item!r}: expected NAME=NUMBER, e.g. {flag} {example}")
    return out


def hydra_app(config_name: str) -> Callable[[Callable[[DictConfig], Any]], Callable[[], Any]]:
    """Decorator for `main(cfg)` functions: our config tree, our error reporting, offline defaults."""

    def decorate(task: Callable[[DictConfig], Any]) -> Callable[[], Any]:
        # Hydra and the config resolvers are imported here, not with this module: the tools that only take
        # flags (predict, scan, report, ...) start about 0.4 s faster without them
        import hydra

        import neuraldem.config  # noqa: F401  (registers resolvers before Hydra composes)

        quiet_environment()
        wrapped = report_user_errors(task)
        return hydra.main(version_base="1.3", config_path=str(config_dir()), config_name=config_name)(wrapped)

    return decorate
