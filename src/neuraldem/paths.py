"""Where datasets, checkpoints and run outputs live: the data dir, never the git checkout.

Resolution order: $NEURALDEM_DATA, then $XDG_DATA_HOME/neuraldem, then ~/.local/share/neuraldem.
Your own configs (scene files written by `neuraldem scene new`) live in the user config folder:
$NEURALDEM_CONFIG, then $XDG_CONFIG_HOME/neuraldem, then ~/.config/neuraldem.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from neuraldem.commands import command_or_module

ENV_VAR = "NEURALDEM_DATA"
CONFIG_ENV_VAR = "NEURALDEM_CONFIG"


def data_dir() -> Path:
    """The data dir (not created here; `ensure_writable_dir` does that where a writer needs it)."""
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env).expanduser().resolve()
    xdg = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return (Path(xdg).expanduser() / "neuraldem").resolve()


def user_config_dir() -> Path:
    """Your own Hydra configs (`data/<scene>.yaml`, ...): every Hydra command searches it after the packaged
    configs (a name that is packaged already is refused, never shadowed). Not created here."""
    env = os.environ.get(CONFIG_ENV_VAR)
    if env:
        return Path(env).expanduser().resolve()
    xdg = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
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


def portable(text: str) -> str:
    """`text` (a recorded command) with this machine's data dir written as $NEURALDEM_DATA and the checkout's
    root dropped, so that a command stored with a result reads the same on every machine."""
    text = text.replace(str(data_dir()), "$" + ENV_VAR)
    root = repo_root()
    return text.replace(str(root) + "/", "") if root is not None else text


def module_command(module: str, argv: list[str] | None = None) -> str:
    """The command that runs `module` (`neuraldem VERB [OBJECT]`, neuraldem.commands) with `argv` (default: this
    process's arguments), portable: what a tool records."""
    return portable(" ".join([command_or_module(module), *(sys.argv[1:] if argv is None else argv)]))


def invocation(argv: list[str] | None = None) -> str:
    """The command line that ran this process, portable: a script of this package (Hydra apps run as
    `python -m neuraldem.train`, whose argv[0] is the file) is written as the command that runs it
    (`neuraldem train ...`), or `python -m neuraldem.<module>` where no verb runs it."""
    argv = list(sys.argv if argv is None else argv)
    if argv and argv[0].endswith(".py"):
        package = Path(__file__).resolve().parent
        script = Path(argv[0]).resolve()
        if script.is_relative_to(package):
            module = ".".join(("neuraldem", *script.relative_to(package).with_suffix("").parts))
            argv[:1] = [command_or_module(module)]
    return portable(" ".join(argv))
