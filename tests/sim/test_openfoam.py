"""The reason recorded for a failed OpenFOAM run is the solver's own error line, never its start-up banner."""

from __future__ import annotations

from pathlib import Path

from neuraldem.sim.openfoam import FoamRun

BANNER = """/*---------------------------------------------------------------------------*\\
Build  : v1912
Exec   : DPMFoam
trapFpe: Floating point exception trapping enabled (FOAM_SIGFPE).
fileModificationChecking : Monitoring run-time modified files using timeStampMaster
Time = 0.0101
"""


def run_with_log(tmp_path: Path, text: str, returncode: int) -> FoamRun:
    log = tmp_path / "log.DPMFoam"
    log.write_text(text)
    return FoamRun("DPMFoam", returncode, 1.0, 1.0, 10.0, False, log)


def test_clean_run_has_no_error(tmp_path: Path):
    assert run_with_log(tmp_path, BANNER + "End\n", 0).error is None


def test_banner_is_not_the_reason(tmp_path: Path):
    error = run_with_log(tmp_path, BANNER, 1).error
    assert error is not None and "trapFpe" not in error and error.startswith("no error message (exit status 1")


def test_real_floating_point_crash_is_the_reason(tmp_path: Path):
    crash = (BANNER + "#0  Foam::error::printStack(Foam::Ostream&)\n#1  Foam::sigFpe::sigHandler(int)\n"
             "Floating point exception (core dumped)\n")
    error = run_with_log(tmp_path, crash, -8).error
    assert error is not None and error.startswith("Floating point exception (core dumped)")


def test_fatal_error_message_is_joined(tmp_path: Path):
    fatal = (BANNER + "\n--> FOAM FATAL ERROR: \ncannot find file \"0/U.air\"\n\n"
             "    From Foam::regIOobject::readStream()\n")
    error = run_with_log(tmp_path, fatal, 1).error
    assert error is not None and error.startswith('FOAM FATAL ERROR: cannot find file "0/U.air"')
