"""Finding OpenFOAM (v1912, Debian package), giving its apps the environment they need, and running them.

Every app runs serially in the case folder with its output in `log.<app>`; CPU time and the time limit come
from the shared process handling in `neuraldem.sim.runner`. A failed run never raises here: `FoamRun.error`
names what went wrong (OpenFOAM's own FATAL ERROR line, a floating point exception, the time limit) and the
caller decides.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

from neuraldem.errors import SolverError
from neuraldem.sim.runner import run_process
from neuraldem.sim.serial_env import serial_solver_env

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
    env = serial_solver_env()  # Open MPI as a singleton (sim.serial_env)
    env["WM_PROJECT_DIR"] = str(pdir)
    env.setdefault("WM_PROJECT", "OpenFOAM")
    env.setdefault("WM_PROJECT_VERSION", "v1912")
    return env


def find_apps(apps: tuple[str, ...] = REQUIRED_APPS) -> dict[str, Path]:
    """Paths of the OpenFOAM executables we drive; SolverError naming the missing ones."""
    found = {app: shutil.which(app) for app in apps}
    missing = [app for app, path in found.items() if path is None]
    if missing:
        raise SolverError(f"OpenFOAM executable(s) {missing} not found on PATH", fix=INSTALL_HINT)
    return {app: Path(path) for app, path in found.items() if path is not None}


_USING_RE = re.compile(r"Using:\s*OpenFOAM-\S*\s*\((\w+)\)")
_BUILD_RE = re.compile(r"Build:\s*.*?\(patch=(\w+)\)")


def foam_version(timeout_s: float = 60.0) -> str:
    """e.g. 'OpenFOAM 1912 (patch 200626)', from `foamDictionary -help`; 'unknown' if it does not say."""
    apps = find_apps(("foamDictionary",))
    try:
        proc = subprocess.run([str(apps["foamDictionary"]), "-help"], env=foam_env(), capture_output=True,
                              text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise SolverError(f"`foamDictionary -help` hung for {timeout_s:.0f} s", fix=INSTALL_HINT) from None
    text = proc.stdout + proc.stderr
    using, build = _USING_RE.search(text), _BUILD_RE.search(text)
    if using is None:
        return "unknown"
    return f"OpenFOAM {using.group(1)}" + (f" (patch {build.group(1)})" if build else "")


# ---- case files

HEADER = """/*--------------------------------*- C++ -*----------------------------------*\\
  written by neuraldem
\\*---------------------------------------------------------------------------*/
FoamFile
{{
    version     2.0;
    format      ascii;
    class       {cls};
{location}    object      {obj};
}}

"""


def write_foam_file(path: Path, cls: str, obj: str, body: str, location: str | None = None) -> None:
    """An ASCII OpenFOAM file: the FoamFile header, then `body` verbatim."""
    path.parent.mkdir(parents=True, exist_ok=True)
    loc = f'    location    "{location}";\n' if location else ""
    path.write_text(HEADER.format(cls=cls, obj=obj, location=loc) + body)


# ---- running apps

# the lines OpenFOAM prints when it gives up; the first one found is the reason
_ERROR_MARKERS = ("--> FOAM FATAL IO ERROR", "--> FOAM FATAL ERROR", "Floating point exception",
                  "Segmentation fault", "sigFpe", "sigSegv", "bad_alloc")

# start-up lines of every run that contain a marker without being an error
_BANNERS = ("trapFpe:",)


@dataclass
class FoamRun:
    app: str
    returncode: int
    wall_s: float
    cpu_s: float
    max_rss_mb: float
    timed_out: bool
    log_path: Path

    @property
    def log(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    @property
    def error(self) -> str | None:
        """None for a clean run, else one line: the solver's own message when it printed one."""
        if self.timed_out:
            return f"killed after the time limit ({self.wall_s:.0f} s wall)"
        log = self.log
        if self.returncode == 0 and "FOAM FATAL" not in log:
            return None
        return f"{_error_detail(log) or 'no error message'} (exit status {self.returncode}; see {self.log_path})"


def _error_detail(log: str) -> str | None:
    lines = log.splitlines()
    for marker in _ERROR_MARKERS:
        for i, line in enumerate(lines):
            if marker in line and not line.startswith(_BANNERS):
                if marker.startswith("-->"):  # the message is on the next non-empty lines
                    following = lines[i + 1:i + 4]
                    detail = " ".join(x.strip() for x in following if x.strip() and not x.startswith("    From"))
                    return f"{marker.lstrip('-> ')}: {detail}".strip()
                return line.strip()
    return None


def run_app(app: str, workdir: Path, args: tuple[str, ...] = (), log_name: str | None = None,
            timeout_s: float | None = None) -> FoamRun:
    """Run an OpenFOAM app in the case `workdir`, output to `log.<app>` (or `log_name`)."""
    exe = find_apps((app,))[app]
    log_path = workdir / (log_name or f"log.{app}")
    res = run_process([str(exe), *args], workdir, foam_env(), log_path, timeout_s)
    return FoamRun(app=app, returncode=res.returncode, wall_s=res.wall_s, cpu_s=res.cpu_s,
                   max_rss_mb=res.max_rss_mb, timed_out=res.timed_out, log_path=log_path)


def require_ok(run: FoamRun, what: str) -> None:
    if run.error:
        raise SolverError(f"{what} failed in {run.log_path.parent}: {run.error}")
