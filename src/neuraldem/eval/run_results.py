"""Finding the evaluation results of trained runs (the `evaluation/metrics.json` a training run with
evaluate=true writes), for the tables that compare runs."""

from __future__ import annotations

import json
from pathlib import Path

from neuraldem.errors import DataError


def find_results(folders: list[Path]) -> list[dict]:
    """Every evaluation/metrics.json under the folders, each with its `path` added, in path order."""
    found = []
    for folder in folders:
        for path in sorted(Path(folder).rglob("evaluation/metrics.json")):
            result = json.loads(path.read_text())
            result["path"] = str(path)
            found.append(result)
    if not found:
        raise DataError(f"no evaluation/metrics.json under {[str(f) for f in folders]}: train with "
                        "evaluate=true (the hopper and fb experiments do) or run python -m neuraldem.evaluate")
    return found
