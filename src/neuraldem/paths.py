"""Where datasets, checkpoints and run outputs live: the data dir, never the git checkout.

Resolution order: $NEURALDEM_DATA, then $XDG_DATA_HOME/neuraldem, then ~/.local/share/neuraldem.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "NEURALDEM_DATA"


def data_dir() -> Path:
    """The data dir (not created here; `ensure_writable_dir` does that where a writer needs it)."""
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env).expanduser().resolve()
    xdg = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return (Path(xdg).expanduser() / "neuraldem").resolve()


def repo_root() -> Path | None:
    """The source checkout this package runs from (editable install), or None for a wheel install."""
    root = Path(__file__).resolve().parents[2]
    return root if (root / "pyproject.toml").is_file() and (root / "conf").is_dir() else None


def config_dir() -> Path:
    """The Hydra config tree: `conf/` of the checkout, or the copy packed inside a wheel."""
    packaged = Path(__file__).resolve().parent / "conf"
    if packaged.is_dir():
        return packaged
    root = repo_root()
    if root is None:
        raise FileNotFoundError(
            "neuraldem's Hydra configs are missing: reinstall with `pip install -e .` from the checkout"
        )
    return root / "conf"


def results_dir() -> Path:
    """Figures and tables that the README quotes: `results/` in the checkout, else under the data dir."""
    root = repo_root()
    return (root / "results") if root is not None else data_dir() / "results"
