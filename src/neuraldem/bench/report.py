"""Writing benchmark results as JSON together with the machine they were measured on."""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path
from typing import Any

from neuraldem.machine import machine_info
from neuraldem.paths import results_dir


def default_path(name: str) -> Path:
    return results_dir() / "bench" / f"{name}.json"


def write_results(name: str, results: Any, *, command: str, path: Path | None = None,
                  machine: dict[str, Any] | None = None) -> Path:
    """Write `{benchmark, date, command, machine, results}` to `path` (default results/bench/NAME.json).

    Pass `machine` taken before a long run so its load average describes the conditions during the run."""
    path = path or default_path(name)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "benchmark": name,
        "date": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "command": command,
        "machine": machine or machine_info(),
        "results": results,
    }
    path.write_text(json.dumps(payload, indent=2) + "\n")
    return path
