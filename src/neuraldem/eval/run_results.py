"""Finding the evaluation results of trained runs (the `evaluation/metrics.json` a training run with
evaluate=true writes), for the tables that compare runs."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

from neuraldem.errors import DataError


def find_results(folders: list[Path]) -> list[dict]:
    """Every evaluation/metrics.json under the folders, each with its `path` and `run` (the run folder relative
    to the folder it was found in, e.g. `fb_base/noise_pf`; where two folders hold runs of that name, e.g. two
    seeds of one sweep, prefixed with the folder's name: `fb_study_seed1/fb_base/noise_pf`) added, in path order."""
    found, roots = [], []
    for folder in folders:
        for path in sorted(Path(folder).rglob("evaluation/metrics.json")):
            result = json.loads(path.read_text())
            result["path"] = str(path)
            result["run"] = str(path.parent.parent.relative_to(folder)) if path.parent.parent != Path(folder) \
                else path.parent.parent.name
            found.append(result)
            roots.append(Path(folder))
    counts = Counter(r["run"] for r in found)
    for result, folder in zip(found, roots):
        if counts[result["run"]] > 1:
            result["run"] = f"{folder.resolve().name}/{result['run']}"
    if not found:
        raise DataError(f"no evaluation/metrics.json under {[str(f) for f in folders]}: train with "
                        "evaluate=true (the hopper and fb experiments do) or run python -m neuraldem.evaluate")
    return found
