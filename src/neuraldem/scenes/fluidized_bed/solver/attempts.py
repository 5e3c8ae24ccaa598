"""The app runs of a fluidized-bed case (blockMesh, writeCellCentres, DPMFoam and its restarts) recorded in
attempts.json, and the cost of a run added up over all of them."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.sim.openfoam import FoamRun

ATTEMPTS = "attempts.json"


def record_attempt(workdir: Path, run: FoamRun, restart: str | None,
                   load: tuple[float, float] | None = None) -> list[dict[str, Any]]:
    """Append one app run (CPU, wall, the machine's 1-min load average before and after) to attempts.json."""
    path = workdir / ATTEMPTS
    attempts = json.loads(path.read_text()) if path.is_file() else []
    attempts.append({"app": run.app, "cpu_s": run.cpu_s, "wall_s": run.wall_s, "returncode": run.returncode,
                     "restart_from": restart, "max_rss_mb": run.max_rss_mb,
                     "load_avg": list(load) if load else None, "log": run.log_path.name})
    path.write_text(json.dumps(attempts, indent=1))
    return attempts


_EXECUTION = re.compile(r"^ExecutionTime = ([\d.eE+-]+) s\s+ClockTime = ([\d.eE+-]+) s", re.MULTILINE)


def record_killed_attempts(workdir: Path) -> None:
    """A DPMFoam killed with its driver never got its attempt recorded: take its CPU time from the last
    `ExecutionTime` line of its log (OpenFOAM's CPU time of the process)."""
    path = workdir / ATTEMPTS
    attempts = json.loads(path.read_text()) if path.is_file() else []
    known = {str(a.get("log")).removesuffix(".gz") for a in attempts}
    for log in sorted(workdir.glob("log.DPMFoam*")):
        if log.name.removesuffix(".gz") in known or log.suffix == ".gz":
            continue
        times = _EXECUTION.findall(log.read_text(errors="replace"))
        cpu, wall = (float(times[-1][0]), float(times[-1][1])) if times else (0.0, 0.0)
        attempts.append({"app": "DPMFoam", "cpu_s": cpu, "wall_s": wall, "returncode": None, "restart_from": None,
                         "max_rss_mb": 0.0, "load_avg": None, "log": log.name, "killed": True})
    path.write_text(json.dumps(attempts, indent=1))


def run_cost(workdir: Path, sim_time: float) -> dict[str, float]:
    path = workdir / ATTEMPTS
    attempts = json.loads(path.read_text()) if path.is_file() else []
    cpu = float(sum(a["cpu_s"] for a in attempts))
    solver_cpu = float(sum(a["cpu_s"] for a in attempts if a["app"] == "DPMFoam"))
    solver_wall = float(sum(a["wall_s"] for a in attempts if a["app"] == "DPMFoam"))
    return {"cpu_s": cpu, "solver_cpu_s": solver_cpu, "wall_s": float(sum(a["wall_s"] for a in attempts)),
            "solver_wall_s": solver_wall,
            "simulated_s": float(sim_time), "cpu_s_per_simulated_s": solver_cpu / sim_time,
            "attempts": float(sum(1 for a in attempts if a["app"] == "DPMFoam")),
            "max_rss_mb": float(max((a["max_rss_mb"] for a in attempts), default=0.0)),
            "load_avg": float(np.mean([x for a in attempts if a["app"] == "DPMFoam" for x in (a.get("load_avg") or [])]
                                      or [np.nan]))}
