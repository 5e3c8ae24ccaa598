"""Finding OpenFOAM (v1912, Debian package) and giving its solvers the environment they need."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from neuraldem.errors import SolverError

DEBIAN_PROJECT_DIR = Path("/usr/share/openfoam")
INSTALL_HINT = "install it with `sudo apt-get install openfoam` (Debian/Ubuntu, OpenFOAM v1912)"
REQUIRED_APPS = ("DPMFoam", "blockMesh", "postProcess", "foamDictionary")


def project_dir() -> Path:
    """$WM_PROJECT_DIR if set, else the Debian location. OpenFOAM reads its `etc/` files from here."""
    env = os.environ.get("WM_PROJECT_DIR")
    return Path(env) if env else DEBIAN_PROJECT_DIR


def foam_env() -> dict[str, str]:
    """Environment for OpenFOAM apps. Sourcing Debian's bashrc fails; the etc dir is all they need."""
    pdir = project_dir()
    if not (pdir / "etc" / "controlDict").is_file():
        raise SolverError(f"OpenFOAM environment not found: {pdir}/etc/controlDict is missing",
                          fix=f"set WM_PROJECT_DIR to your OpenFOAM installation (Debian: {DEBIAN_PROJECT_DIR}) "
                              f"or {INSTALL_HINT}")
    env = dict(os.environ)
    env["WM_PROJECT_DIR"] = str(pdir)
    env.setdefault("WM_PROJECT", "OpenFOAM")
    env.setdefault("WM_PROJECT_VERSION", "v1912")
    env.setdefault("OMPI_ALLOW_RUN_AS_ROOT", "1")
    env.setdefault("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
    return env


def find_apps(apps: tuple[str, ...] = REQUIRED_APPS) -> dict[str, Path]:
    """Paths of the OpenFOAM executables we drive; SolverError naming the missing ones."""
    found = {app: shutil.which(app) for app in apps}
    missing = [app for app, path in found.items() if path is None]
    if missing:
        raise SolverError(f"OpenFOAM executable(s) {missing} not found on PATH", fix=INSTALL_HINT)
    return {app: Path(path) for app, path in found.items() if path is not None}
