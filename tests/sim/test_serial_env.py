"""A serial solver's environment: none of the batch system's variables (inside a Slurm job step Open MPI would
take the solver for an srun-launched process and abort in MPI_Init), Open MPI allowed as root, one thread."""

from __future__ import annotations

import pytest

from neuraldem.sim.liggghts import solver_env
from neuraldem.sim.serial_env import serial_solver_env


def test_batch_system_variables_are_left_out(monkeypatch: pytest.MonkeyPatch):
    for name in ("SLURM_JOB_ID", "SLURM_STEP_ID", "SLURM_ARRAY_TASK_ID", "PMI_FD", "PMIX_RANK"):
        monkeypatch.setenv(name, "7")
    monkeypatch.setenv("NEURALDEM_DATA", "/data")
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    for env in (serial_solver_env(), solver_env()):
        assert not [k for k in env if k.startswith(("SLURM_", "PMI_", "PMIX_"))]
        assert env["NEURALDEM_DATA"] == "/data" and env["OMP_NUM_THREADS"] == "1"
        assert env["OMPI_ALLOW_RUN_AS_ROOT"] == "1" and env["OMPI_ALLOW_RUN_AS_ROOT_CONFIRM"] == "1"
