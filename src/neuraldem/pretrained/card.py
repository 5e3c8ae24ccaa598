"""A released model's card (MODEL_CARD.md beside meta.json): what it was trained on, how it was chosen, how well it
answers against the cheap alternatives and the solver's own spread, which answer to trust, and where it is weak.

The card is written from meta.json by the release that writes meta.json (`write_card`), and records the SHA-256
of the meta.json it describes: the loader refuses a model whose card is missing or describes another meta.json
(`check_card`), naming the file and how to write it again.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from neuraldem.data.integrity import digest
from neuraldem.errors import DataError

CARD = "MODEL_CARD.md"
STAMP = re.compile(r"^meta\.json SHA-256: `([0-9a-f]{64})`$", re.M)
SOURCES = {"field model": "field model", "gp": "GP on the scene parameters", "constant": "training mean",
           "seed floor": "the solver, another packing (seed floor)"}


def _fmt(v: Any) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def errors_table(errors: dict[str, Any]) -> list[str]:
    rows = {k: v for k, v in errors.items() if isinstance(v, dict) and k in SOURCES}
    keys = sorted({k for v in rows.values() for k, x in v.items() if isinstance(x, (int, float)) and k != "n_runs"
                   and k != "n_sims"})
    if not rows or not keys:
        return ["(no test errors recorded)"]
    out = ["| answer | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys)]
    out += [f"| {SOURCES[name]} | " + " | ".join(_fmt(v.get(k, "-")) for k in keys) + " |" for name, v in rows.items()]
    return out


def held_out_line(held: dict[str, Any] | None) -> list[str]:
    if not held:
        return []
    return [f"- test runs from the dataset of held-out runs `{held['dataset']}` (new parameters and start packings), "
            f"manifest SHA-256 `{held.get('manifest_sha256')}`: {', '.join(held.get('run_ids', []))}"]


def render(meta: dict[str, Any], meta_sha: str) -> str:
    data = meta.get("training_data", {})
    held = data.get("test_dataset")  # a dataset of held-out runs, scored instead of the split's test part
    ids = data.get("run_ids", {})
    config = meta.get("config", {})
    lines = [f"# Model card: {meta.get('name')} ({meta.get('kind')})", "", str(meta.get("description", "")), "",
             "## What it answers", ""]
    lines += [f"- {name}: trained on {lo:.4g} .. {hi:.4g}" + (
        f" (asked for {meta['asked_range'][name][0]:.4g} .. {meta['asked_range'][name][1]:.4g})"
        if name in meta.get("asked_range", {}) else "")
              for name, (lo, hi) in meta.get("trained_range", {}).items()]
    lines += ["", "## Data", "",
              f"- dataset `{data.get('dataset')}`, manifest SHA-256 `{data.get('manifest_sha256')}`",
              "- runs: " + ", ".join(f"{part} {len(v)}" for part, v in ids.items()) +
              f" (split `{data.get('split')}`)", *held_out_line(held), "",
              "## Recipe", "",
              f"- training: `{' '.join(config.get('train_overrides', [])) or '(the experiment defaults)'}`, "
              f"step {config.get('global_step')}",
              "- rebuild: " + "; ".join(f"`{c}`" for c in meta.get("rebuild", [])),
              f"- rollout options it answers with: {meta['rollout_options']}" if meta.get("rollout_options") else
              "- rollout options: as trained", ""]
    chosen = meta.get("chosen")
    lines += ["## What validation chose", "", str(chosen) if chosen else
              "(not recorded for this model: it was chosen before the release protocol recorded choices)", ""]
    errors = meta.get("test_errors", {})
    reads = meta.get("test_reads", [])
    if not reads:
        read_note = " (the test reads before the release protocol were not recorded)"
    elif len(reads) == 1:
        read_note = f", read once for this recipe family ({reads[0]['family']}, {reads[0]['date']})"
    else:
        read_note = (f", read {len(reads)} times for this recipe family ({reads[-1]['family']}): "
                     + "; ".join(f"{r['date']} for {r['model']}" for r in reads)
                     + (" -- this release changed the recipe after an earlier read: its test scores are not "
                        "held-out evidence for the change, new test runs are" if reads[-1].get("changed_recipe")
                        else ""))
    where = f" of `{held['dataset']}` (not the training dataset's own test part)" if held else ""
    lines += ["## Test scores", "", f"On {errors.get('n_test_runs', '?')} held-out solver runs{where}{read_note}:", ""]
    lines += errors_table(errors)
    if meta.get("test_errors_outside"):
        lines += ["", "Outside the trained ranges:", ""] + errors_table(meta["test_errors_outside"])
    lines += ["", "## Which answer to trust", "",
              "Per quantity, `neuraldem predict` recommends the answer with the lower validated error above "
              "(`neuraldem.pretrained.trust`); outside the trained ranges it recommends one only where errors were "
              "validated there.", "", "## Stability", ""]
    lines += [str(meta["stability"])] if meta.get("stability") else ["(no stability scan recorded with this model)"]
    lines += ["", "## Known weak regions", ""]
    weak = meta.get("weak_regions") or []
    lines += [f"- {r.get('parameters')}: {r.get('note')}" for r in weak] or ["(none recorded)"]
    lines += ["", f"meta.json SHA-256: `{meta_sha}`", ""]
    return "\n".join(lines)


def write_card(folder: Path) -> Path:
    """MODEL_CARD.md of the model in `folder`, from its meta.json (call after every write of meta.json)."""
    import json

    meta_path = Path(folder) / "meta.json"
    card = Path(folder) / CARD
    card.write_text(render(json.loads(meta_path.read_text()), digest(meta_path)))
    return card


def check_card(folder: Path, rewrite: str) -> None:
    """The card must exist and describe this meta.json; `rewrite` is the command that writes it again."""
    card = Path(folder) / CARD
    if not card.is_file():
        raise DataError(f"{card} is missing: a released model comes with its card", f"write it: {rewrite}")
    found = STAMP.search(card.read_text())
    if found is None or found.group(1) != digest(Path(folder) / "meta.json"):
        raise DataError(f"{card} does not describe {Path(folder) / 'meta.json'} (the SHA-256 it records differs)",
                        f"write it again: {rewrite}")
