"""Finding the evaluation results of trained runs (the `evaluation/metrics.json` a training run with
evaluate=true writes), for the tables that compare runs."""

from __future__ import annotations

import json
from pathlib import Path

from neuraldem.errors import DataError


def find_results(folders: list[Path]) -> list[dict]:
    """Every evaluation/metrics.json under the folders, each with its `path` and `run` (the run folder relative
    to the folder it was found in, e.g. `fb_base/noise_pf`) added, in path order."""
    found = []
    for folder in folders:
        for path in sorted(Path(folder).rglob("evaluation/metrics.json")):
            result = json.loads(path.read_text())
            result["path"] = str(path)
            result["run"] = str(path.parent.parent.relative_to(folder)) if path.parent.parent != Path(folder) \
                else path.parent.parent.name
            found.append(result)
    if not found:
        raise DataError(f"no evaluation/metrics.json under {[str(f) for f in folders]}: train with "
                        "evaluate=true (the hopper and fb experiments do) or run python -m neuraldem.evaluate")
    return found
