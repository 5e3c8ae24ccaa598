"""LIGGGHTS dump and exit-file readers: good files parse; damaged files fail naming file and frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neuraldem.errors import DataError
from neuraldem.sim.dump import read_dump, read_exit_file


def _frame(step: int, rows: list[tuple]) -> str:
    head = (f"ITEM: TIMESTEP\n{step}\nITEM: NUMBER OF ATOMS\n{len(rows)}\nITEM: BOX BOUNDS ff ff ff\n"
            "-1 1\n-1 1\n-1 1\nITEM: ATOMS id x y z vx vy vz \n")
    return head + "".join(" ".join(str(v) for v in r) + " \n" for r in rows)


@pytest.fixture
def dump(tmp_path: Path) -> Path:
    p = tmp_path / "dump.txt"
    p.write_text(_frame(100, [(1, 0.1, 0.2, 0.3, 0, 0, -1), (2, 0.0, 0.0, 0.5, 0, 0, 0)])
                 + _frame(200, [(2, 0.0, 0.0, 0.4, 0, 0, -0.1)]))
    return p


def test_reads_frames(dump: Path):
    frames = read_dump(dump)
    assert [f.step for f in frames] == [100, 200]
    assert frames[0].data.shape == (2, 7)
    np.testing.assert_allclose(frames[1].column("z"), [0.4])


def test_truncated_last_frame(dump: Path):
    text = dump.read_text()
    dump.write_text(text[: len(text) - 12])
    with pytest.raises(DataError, match=r"dump\.txt: frame 1: truncated"):
        read_dump(dump)
    assert [f.step for f in read_dump(dump, drop_truncated_tail=True)] == [100]


def test_damage_in_the_middle_is_always_an_error(tmp_path: Path):
    p = tmp_path / "d.txt"
    p.write_text(_frame(100, [(1, 0.1, 0.2, 0.3, 0, 0, -1)]).replace("0.3", "abc") + _frame(200, []))
    with pytest.raises(DataError, match="frame 0: non-numeric"):
        read_dump(p, drop_truncated_tail=True)


def test_missing_column_names_the_fix(tmp_path: Path):
    p = tmp_path / "d.txt"
    p.write_text(_frame(1, [(1, 0.1, 0.2, 0.3, 0, 0, 0)]).replace("vx vy vz", "fx fy fz"))
    with pytest.raises(DataError, match=r"columns \['vx'\] missing.*dump custom"):
        read_dump(p, required=("id", "x", "vx"))


def test_nan_and_wrong_files(tmp_path: Path):
    p = tmp_path / "d.txt"
    p.write_text(_frame(1, [(1, "nan", 0.2, 0.3, 0, 0, 0)]))
    with pytest.raises(DataError, match="NaN"):
        read_dump(p)
    p.write_text("hello\n")
    with pytest.raises(DataError, match="not a LIGGGHTS/LAMMPS dump"):
        read_dump(p)
    with pytest.raises(DataError, match="does not exist"):
        read_dump(tmp_path / "missing.txt")


def test_exit_file(tmp_path: Path):
    p = tmp_path / "exits.txt"
    p.write_text("# ID time  diameter x y z u v w\n39  0.3998  0.01 0 0 -0.05 0 0 -1\n172 0.4028 0.01 0 0 0 0 0 0\n")
    ids, times = read_exit_file(p)
    assert ids.tolist() == [39, 172] and times.tolist() == [0.3998, 0.4028]
    p.write_text("39 0.3\n39 0.4\n")
    with pytest.raises(DataError, match="exits twice"):
        read_exit_file(p)
