"""Finding the evaluation results of trained runs (the `evaluation/metrics.json` a training run with
evaluate=true writes), for the tables that compare runs."""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from pathlib import Path

from neuraldem.cli import doc_parser
from neuraldem.data.schema import atomic_write_json
from neuraldem.errors import DataError


def disambiguate(found: list[dict], roots: list[Path]) -> None:
    """Where two folders hold runs of one name (e.g. two seeds of one sweep), prefix each with its folder's name."""
    folders: dict[str, set[Path]] = {}
    for result, folder in zip(found, roots, strict=False):
        folders.setdefault(result["run"], set()).add(folder)
    for result, folder in zip(found, roots, strict=False):
        if len(folders[result["run"]]) > 1:
            result["run"] = f"{folder.resolve().name}/{result['run']}"


def scan_results(folders: list[Path], pattern: str = "evaluation/metrics.json",
                 keep: Callable[[dict], bool] = lambda result: True) -> list[dict]:
    """Every metrics file matching `pattern` under the folders that `keep` accepts, each with its `path` and
    `run` (the run folder, the folder above the evaluation folder, relative to the folder it was found in, e.g.
    `fb_base/noise_pf`; where two folders hold runs of that name, e.g. two seeds of one sweep, prefixed with the
    folder's name: `fb_study_seed1/fb_base/noise_pf`) added, in path order. Possibly empty."""
    found, roots = [], []
    for folder in folders:
        for path in sorted(Path(folder).rglob(pattern)):
            result = json.loads(path.read_text())
            if not keep(result):
                continue
            result["path"] = str(path)
            run = path.parent.parent
            result["run"] = str(run.relative_to(folder)) if run != Path(folder) else run.name
            found.append(result)
            roots.append(Path(folder))
    disambiguate(found, roots)
    return found


def find_results(folders: list[Path]) -> list[dict]:
    """Every evaluation/metrics.json under the folders (`scan_results`); refused when there is none."""
    found = scan_results(folders)
    if not found:
        raise DataError(f"no evaluation/metrics.json under {[str(f) for f in folders]}: train with "
                        "evaluate=true (the hopper and fb experiments do) or run neuraldem evaluate ckpt=...")
    return found


def table_main(argv: list[str] | None, prog: str, doc: str | None, collect: Callable[[list[Path]], list[dict]],
               render: Callable[[list[dict]], str], summary: Callable[[dict], dict]) -> int:
    """The command line of the collectors: `prog folders=[FOLDER,...] out=FILE.md` writes render(results) to FILE.md and
    summary(result) of every result to FILE.json beside it, and prints the table."""
    p = doc_parser(prog, doc)
    p.add_argument("folders", type=Path, nargs="+")
    p.add_argument("--out", type=Path, required=True,
                   help="markdown file (a .json with the same numbers is written beside it)")
    a = p.parse_args(argv)
    results = collect(a.folders)
    text = render(results)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(text)
    atomic_write_json(a.out.with_suffix(".json"), [summary(r) for r in results])
    print(text)
    return 0


def logged_losses(run: Path) -> dict[tuple[int, str], float]:
    """(step, name) -> value of every train/ and val/ value the CSV logger wrote in a run folder (under DDP
    rank 0's: the mean over the processes)."""
    out = {}
    with open(run / "csv" / "metrics.csv") as fh:
        for row in csv.DictReader(fh):
            for name, value in row.items():
                if value and name.split("/")[0] in ("train", "val"):
                    out[(int(row["step"]), name)] = float(value)
    return out

