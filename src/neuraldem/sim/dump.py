"""Readers for LIGGGHTS/LAMMPS text output: `dump custom` files and the massflow/mesh exit file.

They validate as they read and name the file and the frame in every error, because a truncated dump
(a killed run, a full disk) must never be mistaken for a complete one.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neuraldem.errors import DataError

TEXT_DUMP = "write it with `dump custom` as text (not binary, not gzipped)"


@dataclass
class DumpFrame:
    step: int
    columns: list[str]
    data: np.ndarray  # (n_atoms, n_columns) float64

    def column(self, name: str) -> np.ndarray:
        return self.data[:, self.columns.index(name)]


def read_dump(path: Path, required: tuple[str, ...] = ("id", "x", "y", "z"),
              drop_truncated_tail: bool = False) -> list[DumpFrame]:
    """All frames of a text `dump custom` file.

    A last frame with fewer values than announced is an error unless `drop_truncated_tail` (then it is
    dropped); damage anywhere else is always an error."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"dump file {path} does not exist")
    text = path.read_text(errors="replace")
    blocks = text.split("ITEM: TIMESTEP")
    if blocks[0].strip():
        raise DataError(f"{path}: not a LIGGGHTS/LAMMPS dump (does not start with 'ITEM: TIMESTEP')")
    frames: list[DumpFrame] = []
    n_blocks = len(blocks) - 1
    if n_blocks == 0:
        raise DataError(f"{path}: no frames (empty or not a dump file)")
    for k, block in enumerate(blocks[1:]):
        last = k == n_blocks - 1
        try:
            frames.append(_parse_block(block, required))
        except DataError as err:
            if last and drop_truncated_tail:
                break
            fix = err.fix
            if last and err.problem.startswith("truncated"):
                fix = ("a killed run? pass drop_truncated_tail=true (neuraldem import liggghts) to keep the complete "
                       "frames")
            raise DataError(f"{path}: frame {k}: {err.problem}", fix) from None
    steps = [f.step for f in frames]
    if any(b <= a for a, b in zip(steps, steps[1:], strict=False)):
        raise DataError(f"{path}: timesteps are not increasing ({steps[:5]}...); two runs appended to one file?")
    return frames


def _parse_block(block: str, required: tuple[str, ...]) -> DumpFrame:
    lines = block.lstrip("\n").split("\n", 8)
    if len(lines) < 8 or not lines[1].startswith("ITEM: NUMBER OF ATOMS") or not lines[7].startswith(
            "ITEM: ATOMS"):
        raise DataError("header incomplete (expected TIMESTEP, NUMBER OF ATOMS, BOX BOUNDS, ATOMS)", TEXT_DUMP)
    try:
        step = int(lines[0])
        n = int(lines[2])
    except ValueError:
        raise DataError("timestep or atom count is not an integer", TEXT_DUMP) from None
    columns = lines[7].split()[2:]
    missing = [c for c in required if c not in columns]
    if missing:
        raise DataError(f"columns {missing} missing (has {columns})", "add them to the `dump custom` command")
    body = lines[8] if len(lines) > 8 else ""
    try:
        values = np.array(body.split(), dtype=np.float64)
    except ValueError:
        raise DataError("non-numeric value in the atom lines", f"the file is damaged or not a text dump: {TEXT_DUMP}"
                        ) from None
    if values.size != n * len(columns):
        raise DataError(f"truncated: {n} atoms x {len(columns)} columns announced, {values.size} values found",
                        "the file is damaged: rerun the solver, or cut the dump before this frame")
    if not np.isfinite(values).all():
        raise DataError("NaN or inf in the atom data",
                        "the solver diverged: rerun it with a smaller timestep, or cut the dump before this frame")
    return DumpFrame(step=step, columns=columns, data=values.reshape(n, len(columns)))


def read_exit_file(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(ids, absolute exit times) from a `fix massflow/mesh ... file F writeTime` output."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"exit file {path} does not exist")
    rows = []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split()
        try:
            rows.append((int(float(parts[0])), float(parts[1])))
        except (ValueError, IndexError):
            raise DataError(f"{path}:{lineno}: expected 'id time ...', got {s[:60]!r}",
                            "one 'id time' pair per line, as `fix massflow/mesh ... file F writeTime` writes it"
                            ) from None
    if not rows:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    arr = np.array(rows)
    ids = arr[:, 0].astype(np.int64)
    if len(np.unique(ids)) != len(ids):
        raise DataError(f"{path}: a particle id exits twice (use `count once` in fix massflow/mesh)")
    return ids, arr[:, 1]
