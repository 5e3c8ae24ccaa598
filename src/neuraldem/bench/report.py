"""Writing benchmark results as JSON together with the machine they were measured on."""

from __future__ import annotations

import datetime as dt
import json
import shlex
import sys
from pathlib import Path
from typing import Any

from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import ConfigError, DataError
from neuraldem.machine import machine_info
from neuraldem.paths import portable, results_dir

# Where each benchmark writes by default: the folder of results/ that answers its question (results/README.md is
# the index). A name not listed here goes to results/bench/.
RESULT_FOLDERS = {
    "hopper_speed": "hopper/speed", "hopper_scaling": "hopper/speed", "seed_floor": "hopper/accuracy",
    "hopper_stability": "hopper/stability", "whatif": "hopper/whatif",
    "query_budget": "hopper/speed", "runtime": "hopper/speed",
    "fb_speed": "fluidized_bed/speed", "fb_runtime": "fluidized_bed/speed", "fb_batch": "fluidized_bed/speed",
    "fb_stability": "fluidized_bed/stability",
    "gns_stability": "fluidized_bed/stability", "whatif_fb": "fluidized_bed/whatif",
    "speed_accuracy": "speed_accuracy", "right_sizing": "speed_accuracy", "fb_speed_accuracy": "speed_accuracy",
    "serve_latency": "explorer", "serve_latency_fb": "explorer",
    "cluster_cost": "cluster", "model_step": "cluster",
}


def default_path(name: str) -> Path:
    """results/<question>/NAME.json (RESULT_FOLDERS), results/bench/NAME.json for a benchmark not listed there."""
    return results_dir() / RESULT_FOLDERS.get(name, "bench") / f"{name}.json"


def write_results(name: str, results: Any, *, command: str, path: Path | None = None,
                  machine: dict[str, Any] | None = None) -> Path:
    """Write `{benchmark, date, command, machine, results}` to `path` (default `default_path(name)`).

    Pass `machine` taken before a long run so its load average describes the conditions during the run.
    Written atomically: a benchmark killed while writing leaves the previous results intact."""
    path = path or default_path(name)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "benchmark": name,
        "date": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "command": portable(command),
        "machine": machine or machine_info(),
        "results": results,
    }
    atomic_write_json(path, payload)
    return path


def write_report(name: str, results: Any, markdown: str, *, command: str, path: Path,
                 machine: dict[str, Any] | None = None) -> Path:
    """`write_results`, the markdown table beside it (same name, .md), and the table on stdout."""
    write_results(name, results, command=command, path=path, machine=machine)
    path.with_suffix(".md").write_text(markdown)
    print(markdown)
    return path


def resolve_out(out: Path | None, name: str) -> Path:
    """Where benchmark `name` writes its JSON: `out=` as a .json file, or a folder (existing, or named without
    a suffix) to hold NAME.json; default `default_path(name)`. Figures and tables go beside the JSON."""
    if out is None:
        return default_path(name)
    out = Path(out)
    if out.is_dir() or not out.suffix:
        return out / f"{name}.json"
    if out.suffix != ".json":
        raise ConfigError(f"out={out} is invalid: pass a .json file or a folder (figures are written beside the "
                          f"JSON), e.g. out={portable(str(default_path(name)))}")
    return out


def command_line(name: str, argv: list[str]) -> str:
    """The command that reproduces a result, recorded with it."""
    return portable(shlex.join(["neuraldem", "bench", name, *argv]))


def read_results(path: Path, name: str) -> dict[str, Any]:
    """A results file written by benchmark `name` (to re-render its figures and tables without measuring)."""
    path = Path(path)
    try:
        payload = json.loads(path.read_text())
    except FileNotFoundError:
        raise DataError(f"no results at {path}: run `neuraldem bench {name}` first") from None
    except json.JSONDecodeError as err:
        raise DataError(f"{path} is not valid JSON ({err}): rerun `neuraldem bench {name}`") from None
    if payload.get("benchmark") != name:
        raise DataError(f"{path} holds results of benchmark {payload.get('benchmark')!r}, not {name!r}: pass the "
                        f"file written by `neuraldem bench {name}`")
    return payload


QUIET_LOAD = 0.5  # 1-minute load average above which other processes compete with a measurement


def warn_if_busy(machine: dict[str, Any]) -> str | None:
    """A warning line when the machine was busy as the measurement began (timings then overstate costs)."""
    load = (machine.get("load_average_1_5_15min") or [0.0])[0]
    if load > QUIET_LOAD:
        msg = (f"warning: 1-minute load average {load:.2f} > {QUIET_LOAD}: other processes compete with this "
               "measurement; take the figures you publish on a quiet machine (docs/benchmarks.md)")
        print(msg, file=sys.stderr)
        return msg
    return None


def machine_at_start() -> dict[str, Any]:
    """The machine as a measurement begins, warning on stderr when it is busy (`warn_if_busy`)."""
    machine = machine_info()
    warn_if_busy(machine)
    return machine
