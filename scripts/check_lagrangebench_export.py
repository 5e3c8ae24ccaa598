"""Read a `neuraldem export lagrangebench` folder with LagrangeBench's own dataset class and compare.

    pip download --no-deps -d /tmp/lb lagrangebench && unzip -q -o /tmp/lb/lagrangebench-*.whl -d /tmp/lb
    python scripts/check_lagrangebench_export.py /tmp/lb EXPORT_DIR

Loads `lagrangebench/data/data.py` (its `H5Dataset`) from the unpacked wheel without installing the package:
the package's `__init__` imports its models (JAX, Haiku, jax-md), which reading data does not need. Two
stand-ins make that file importable here, and neither is in the reading path: `jax.numpy` is numpy (the class
uses it for one cumulative sum of window counts) and `lagrangebench.utils` holds only `NodeType.PAD_VALUE`.
For every split the export has, it builds the training-window dataset and the rollout dataset as LagrangeBench
does, and checks that its windows and trajectories equal what neuraldem's own reader (`read_export`) returns.
"""

from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path

import numpy as np


def load_h5dataset(unpacked: Path) -> type:
    source = unpacked / "lagrangebench" / "data" / "data.py"
    if not source.is_file():
        raise SystemExit(f"{source} not found: unzip the lagrangebench wheel into {unpacked}")
    jax = types.ModuleType("jax")
    jax.numpy = np  # type: ignore[attr-defined]
    utils = types.ModuleType("lagrangebench.utils")
    utils.NodeType = types.SimpleNamespace(PAD_VALUE=-1)  # type: ignore[attr-defined]
    sys.modules.update({"jax": jax, "jax.numpy": np, "lagrangebench": types.ModuleType("lagrangebench"),
                        "lagrangebench.utils": utils})
    spec = importlib.util.spec_from_file_location("lagrangebench.data.data", source)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module.H5Dataset


def main(argv: list[str]) -> int:
    from neuraldem.export.formats import read_export

    unpacked, export_dir = Path(argv[0]), Path(argv[1])
    H5Dataset = load_h5dataset(unpacked)
    ours = read_export(export_dir)
    for split, part in (("train", "train"), ("valid", "val"), ("test", "test")):
        if not (export_dir / f"{split}.h5").is_file():
            print(f"{split}: no file (the split has no runs for it)")
            continue
        trajectories = ours.parts[part]
        windows = H5Dataset(split, str(export_dir), name="neuraldem", input_seq_length=6)
        rollouts = H5Dataset(split, str(export_dir), name="neuraldem", is_rollout=True)
        assert len(rollouts) == len(trajectories), (len(rollouts), len(trajectories))
        for k, traj in enumerate(trajectories):
            pos, types_ = rollouts[k]  # (N, T, D) as LagrangeBench returns it
            n, t = traj.positions.shape[1], pos.shape[1]
            np.testing.assert_array_equal(pos[:n], np.moveaxis(traj.positions[:t], 0, 1))
            assert (types_[:n] == traj.particle_type).all()
        first, types_ = windows[0]
        print(f"{split}: {len(rollouts)} trajectories of {rollouts.sequence_length} snapshots, "
              f"{len(windows)} training windows of {first.shape[1]} snapshots x {first.shape[0]} particles: equal to "
              "neuraldem's reader")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
