"""Finding and running the LIGGGHTS binary (serial; independent runs go side by side, not through MPI)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

from neuraldem.errors import SolverError
from neuraldem.sim.serial_env import serial_solver_env

BINARY_ENV = "NEURALDEM_LIGGGHTS"
INSTALL_HINT = (
    "install it with `sudo apt-get install liggghts` (Debian/Ubuntu), or point "
    f"${BINARY_ENV} at your LIGGGHTS 3.8 executable"
)


def find_liggghts() -> Path:
    """The LIGGGHTS executable: $NEURALDEM_LIGGGHTS, else `liggghts` on PATH."""
    name = os.environ.get(BINARY_ENV, "liggghts")
    found = shutil.which(name)
    if found is None:
        raise SolverError(f"LIGGGHTS executable {name!r} not found on PATH", fix=INSTALL_HINT)
    return Path(found)


def solver_env() -> dict[str, str]:
    """Environment for a serial LIGGGHTS run (`sim.serial_env`: Open MPI as a singleton)."""
    return serial_solver_env()


_VERSION_RE = re.compile(r"LIGGGHTS \(Version ([^,)]+)")


def parse_version(screen: str) -> str | None:
    m = _VERSION_RE.search(screen)
    return m.group(1).strip() if m else None


# A single sphere falling freely for 100 steps of 1e-4 s: z = 0.05 - g t^2 / 2 exactly (Verlet is exact
# for constant acceleration), so the check verifies the binary, the granular package and the integrator.
FREE_FALL_INPUT = """\
atom_style granular
atom_modify map array
boundary f f f
newton off
communicate single vel yes
units si
region box block -0.05 0.05 -0.05 0.05 0 0.1 units box
create_box 1 box
neighbor 0.002 bin
fix m1 all property/global youngsModulus peratomtype 1e7
fix m2 all property/global poissonsRatio peratomtype 0.3
fix m3 all property/global coefficientRestitution peratomtypepair 1 0.5
fix m4 all property/global coefficientFriction peratomtypepair 1 0.5
pair_style gran model hertz tangential history
pair_coeff * *
timestep 1e-4
create_atoms 1 single 0 0 0.05 units box
set atom 1 diameter 0.01 density 2500
fix g all gravity 9.81 vector 0 0 -1
fix i all nve/sphere
run 100
variable z equal z[1]
print "NEURALDEM_Z ${z}"
"""
FREE_FALL_EXPECTED_Z = 0.05 - 0.5 * 9.81 * (100 * 1e-4) ** 2


def free_fall_check(workdir: Path, timeout_s: float = 60.0) -> tuple[str | None, float]:
    """Run the free-fall input; return (version string, final z). Raises SolverError on any failure."""
    exe = find_liggghts()
    workdir.mkdir(parents=True, exist_ok=True)
    (workdir / "in.check").write_text(FREE_FALL_INPUT)
    try:
        proc = subprocess.run([str(exe), "-in", "in.check", "-log", "none"], cwd=workdir, env=solver_env(),
                              capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired as err:
        raise SolverError(f"LIGGGHTS ({exe}) did not finish a 100-step test in {timeout_s:.0f} s") from err
    out = proc.stdout + proc.stderr
    m = re.search(r"NEURALDEM_Z\s+(\S+)", out)
    if proc.returncode != 0 or m is None:
        tail = " | ".join(out.strip().splitlines()[-3:]) or "no output"
        raise SolverError(f"LIGGGHTS ({exe}) failed the 10-line test (exit {proc.returncode}): {tail}")
    return parse_version(out), float(m.group(1))


def preamble(boundary: str = "f f f") -> str:
    """Common head of every granular input: SI units, granular atoms, soft particles allowed (E < 5 MPa)."""
    return (
        "atom_style granular\n"
        "atom_modify map array\n"
        f"boundary {boundary}\n"
        "newton off\n"
        "communicate single vel yes\n"
        "units si\n"
        "soft_particles yes\n"
        "processors * * 1\n"
    )
