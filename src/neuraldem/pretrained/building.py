"""What every shipped model folder is made of, whatever its scene: the checkpoint without optimizer state, the
record of what it was trained on and with (meta.json), and how to rebuild it. The scenes' release modules
(`Scene.release`) add their own files and scores; `neuraldem release` runs them.
"""

from __future__ import annotations

import subprocess
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch
import yaml

from neuraldem.data.integrity import digest
from neuraldem.data.manifest import Manifest
from neuraldem.paths import data_dir

KEEP = ("state_dict", "hyper_parameters", "pytorch-lightning_version", "global_step", "epoch")


def strip_checkpoint(ckpt: Path, out: Path) -> None:
    """The weights and what rebuilds the module, without optimizer states and loop counters."""
    from neuraldem.eval.checkpoints import read_checkpoint

    raw = read_checkpoint(ckpt).raw  # the process's one read of it
    torch.save({k: raw[k] for k in KEEP if k in raw}, out)


def training_inputs(ckpt: Path, kind: str, dataset: Path | None) -> tuple[dict[str, Any], Path, Manifest]:
    """A checkpoint's metadata (of scene `kind`, else refused with the command that trains one), its dataset
    dir (default: <data dir>/datasets/<its data name>) and that dataset's manifest."""
    from neuraldem.eval.checkpoints import read_checkpoint, require_kind

    meta = read_checkpoint(ckpt).metadata
    require_kind(meta, kind, Path(ckpt), "building a shipped model")
    dataset = dataset or data_dir() / "datasets" / meta["data_name"]
    return meta, dataset, Manifest.load(dataset)


def run_folder(ckpt: Path) -> Path | None:
    """The training run a checkpoint belongs to: the folder with its `.hydra/overrides.yaml` among the checkpoint's
    nearest parents (RUN/checkpoints/last.ckpt, RUN/checkpoints/all/stepN.ckpt)."""
    for parent in list(Path(ckpt).parents)[:3]:
        if (parent / ".hydra" / "overrides.yaml").is_file():
            return parent
    return None


def run_overrides(ckpt: Path) -> list[str]:
    run = run_folder(ckpt)
    return list(yaml.safe_load((run / ".hydra" / "overrides.yaml").read_text())) if run is not None else []


def commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def build_record(ckpt: Path, name: str, kind: str, folder: Path, files: dict[str, str], description: str,
                 inputs: list[str], trained_range: dict[str, list[float]], training_data: dict[str, Any],
                 extra: dict[str, Any], build_flags: str = "") -> dict[str, Any]:
    """meta.json of a shipped model: what its files are (with checksums), what it was trained on and with,
    what it scored, and how to rebuild it."""
    from neuraldem.eval.checkpoints import read_checkpoint

    checkpoint = read_checkpoint(ckpt).raw
    hp = checkpoint.get("hyper_parameters", {})
    overrides = run_overrides(Path(ckpt))
    return {
        "name": name, "kind": kind, "description": description, "inputs": inputs, "trained_range": trained_range,
        "files": {role: {"file": f, "sha256": digest(folder / f), "bytes": (folder / f).stat().st_size}
                  for role, f in files.items()},
        "training_data": training_data,
        "config": {"net": hp.get("net"), "optimizer": hp.get("optimizer"), "scheduler": hp.get("scheduler"),
                   "global_step": int(checkpoint.get("global_step", -1)), "train_overrides": overrides},
        **extra,
        "rebuild": [" ".join(["neuraldem train", *overrides]),
                    f"neuraldem release ckpt=<that run>/{in_run(Path(ckpt))} "
                    f"name={name}{' ' + build_flags if build_flags else ''}"],
        "built_from": {"checkpoint": str(Path(ckpt).resolve()), "commit": commit(),
                       "date_utc": datetime.now(UTC).isoformat(timespec="seconds")},
    }


def in_run(ckpt: Path) -> str:
    """The checkpoint's path inside its run folder (checkpoints/<name> when the run is not found)."""
    run = run_folder(ckpt)
    return ckpt.relative_to(run).as_posix() if run is not None else f"checkpoints/{ckpt.name}"


# ---- the sealed test split: every read of a dataset's test runs for a release is recorded beside the dataset
TEST_READS = "test_reads.json"
NOT_THE_RECIPE = ("seed=", "trainer", "logger", "callbacks.progress", "hydra.", "paths.", "evaluate=", "ckpt_path=")


def recipe_of(ckpt: Path) -> tuple[str, list[str]]:
    """(recipe family, recipe) of a checkpoint: its experiment, and its training overrides besides the seed and
    where and how it ran (trainer, logger, paths)."""
    overrides = run_overrides(Path(ckpt))
    family = next((o.split("=", 1)[1] for o in overrides if o.startswith("experiment=")), "custom")
    return family, sorted(o for o in overrides if not o.startswith(NOT_THE_RECIPE))


def read_test_split(dataset: Path, ckpt: Path, name: str, reuse: bool = False) -> list[dict[str, Any]]:
    """Record that the release of `name` reads the test runs of `dataset`, and return every read of them for the
    same recipe family (this one last), for the model card. A changed recipe of a family whose test runs were
    already read is refused unless `reuse` (then the card says so): a recipe changed after a test result needs
    new test runs."""
    import json

    from neuraldem.data.schema import atomic_write_json
    from neuraldem.errors import ConfigError

    family, recipe = recipe_of(ckpt)
    path = Path(dataset) / TEST_READS
    reads = json.loads(path.read_text()) if path.is_file() else []
    same = [r for r in reads if r["family"] == family]
    changed = [r for r in same if r["recipe"] != recipe]
    if changed and not reuse:
        raise ConfigError(f"the test runs of {Path(dataset).name} were read on {changed[-1]['date']} for model "
                          f"{changed[-1]['model']!r} of recipe family {family!r} with another recipe: a changed "
                          "recipe needs new test runs",
                          "generate them (neuraldem datagen ... first=[...]) and release on those, or reuse_test=true "
                          "to release anyway (the model card then says so)")
    entry = {"date": datetime.now(UTC).isoformat(timespec="seconds"), "model": name, "family": family,
             "recipe": recipe, "checkpoint": str(Path(ckpt).resolve()), "changed_recipe": bool(changed)}
    atomic_write_json(path, [*reads, entry])
    return [*same, entry]
