"""The environment of a serial solver process: Open MPI as a singleton, on any machine and inside any job.

LIGGGHTS and OpenFOAM are Debian builds linked with Open MPI, which a serial run still initialises:
- as root it refuses to start unless allowed (`OMPI_ALLOW_RUN_AS_ROOT*`);
- inside a Slurm job step (an array task of `neuraldem datagen executor=slurm`) it finds the step's SLURM_*
  variables, takes itself for a process srun launched, and aborts in MPI_Init ("OMPI was not built with SLURM's
  PMI support"). The solver is one serial process that never talks to the batch system, so it gets none of the
  batch system's variables (SLURM_*, PMI_*, PMIX_*).
"""

from __future__ import annotations

import os

BATCH_SYSTEM_PREFIXES = ("SLURM_", "PMI_", "PMIX_")


def serial_solver_env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(BATCH_SYSTEM_PREFIXES)}
    env.setdefault("OMPI_ALLOW_RUN_AS_ROOT", "1")
    env.setdefault("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
    env.setdefault("OMP_NUM_THREADS", "1")
    return env
