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


def run_overrides(ckpt: Path) -> list[str]:
    path = ckpt.parent.parent / ".hydra" / "overrides.yaml"
    return list(yaml.safe_load(path.read_text())) if path.is_file() else []


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
                    f"neuraldem release ckpt=<that run>/checkpoints/{Path(ckpt).name} "
                    f"name={name}{' ' + build_flags if build_flags else ''}"],
        "built_from": {"checkpoint": str(Path(ckpt).resolve()), "commit": commit(),
                       "date_utc": datetime.now(UTC).isoformat(timespec="seconds")},
    }
