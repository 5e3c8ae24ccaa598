"""The old spellings of the bed's rollout options, read for one more release, each with a note naming the new one.

The six rollout options (`options.RolloutOptions`) are typed `rollout.<name>=VALUE` on every command. Before, they
had other names on each surface; this module is the only place those still appear:

- training: `model.stability.<name>` (an override, or a key of a config file) -> `rollout.<name>`;
- `neuraldem evaluate`: `fluidized_bed.<name>` and `fluidized_bed.conserve_solid_volume` -> `rollout.<name>`,
  `rollout.conserve_volume`;
- `neuraldem evaluate rollout`: the top-level `<name>` and `conserve_solid_volume` -> the same;
- the tools (`report fb-select`, `bench fb_stability`, `bench fb_speed`, `release`): `--rollout-noise X`,
  `--advection-correction X`, `--mirror-alternate` -> `rollout.rollout_noise=X`, ... (cli.py's note says it).

The results files keep the name `conserve_solid_volume` for the volume projection a rollout used (metrics.json,
rollout.json, the rollout HDF5 attributes): stored results and their readers stay valid (`RESULT_CONSERVE_KEY`).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from typing import Any

# the key the results files give the volume projection of a rollout (the option is `conserve_volume`)
RESULT_CONSERVE_KEY = "conserve_solid_volume"

# Hydra overrides, by the config the command composes: old key -> new key (the bed's `Scene.renamed_keys`,
# which neuraldem.cli applies before Hydra reads the command line)
RENAMED_OVERRIDES: dict[str, dict[str, str]] = {
    "train": {
        "model.stability.conserve_volume": "rollout.conserve_volume",
        "model.stability.mixing": "rollout.mixing",
        "model.stability.advection_correction": "rollout.advection_correction",
        "model.stability.advection_flux": "rollout.advection_flux",
        "model.stability.mirror_alternate": "rollout.mirror_alternate",
        "model.stability.rollout_noise": "rollout.rollout_noise",
    },
    "evaluate": {
        "fluidized_bed.conserve_solid_volume": "rollout.conserve_volume",
        "fluidized_bed.mixing": "rollout.mixing",
        "fluidized_bed.advection_correction": "rollout.advection_correction",
        "fluidized_bed.advection_flux": "rollout.advection_flux",
        "fluidized_bed.mirror_alternate": "rollout.mirror_alternate",
        "fluidized_bed.rollout_noise": "rollout.rollout_noise",
    },
    "rollout": {
        "conserve_solid_volume": "rollout.conserve_volume",
        "mixing": "rollout.mixing",
        "advection_correction": "rollout.advection_correction",
        "mirror_alternate": "rollout.mirror_alternate",
        "rollout_noise": "rollout.rollout_noise",
    },
}

# the tools' old flags: option string -> the option's name (each takes a value but --mirror-alternate)
OLD_FLAGS = {"--rollout-noise": "rollout_noise", "--advection-correction": "advection_correction",
             "--mirror-alternate": "mirror_alternate"}

STABILITY_PREFIX = "model.stability."


def note(old: str, new: str) -> None:
    print(f"neuraldem: note: {old} is the old spelling (kept for one release): write {new}", file=sys.stderr)


def moved_stability_options(stability: dict[str, Any],
                            rollout: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """A training config's `model.stability` without the rollout options, and its `rollout` group with those
    that were set under `model.stability` (the old spelling, in a config file) where the group leaves them unset."""
    rollout = dict(rollout)
    for old, new in RENAMED_OVERRIDES["train"].items():
        name = old.removeprefix(STABILITY_PREFIX)
        if name not in stability:
            continue
        value = stability.pop(name)
        if value is None:
            continue
        if rollout.get(name) is None:
            note(f"{old} in a config", f"{new}")
            rollout[name] = value
        elif rollout[name] != value:
            note(f"{old} in a config", f"{new} (its value {rollout[name]!r} is used, not {value!r})")
    return stability, rollout


def add_old_flags(p: argparse.ArgumentParser, names: Iterable[str]) -> None:
    """The old flags of the rollout options `names`, hidden from the help: the same destination as the new
    option (`rollout.<name>`), so the rest of a tool never sees which spelling was used."""
    for flag, name in OLD_FLAGS.items():
        if name not in names:
            continue
        if name == "mirror_alternate":  # was a bare switch
            p.add_argument(flag, dest=f"rollout.{name}", action="store_const", const="true", default=None,
                           help=argparse.SUPPRESS)
        else:
            p.add_argument(flag, dest=f"rollout.{name}", default=None, help=argparse.SUPPRESS)
