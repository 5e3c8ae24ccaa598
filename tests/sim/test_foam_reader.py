"""OpenFOAM output readers: every list form OpenFOAM writes, damaged files named in the error, and a real
DPMFoam case read back consistently."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from neuraldem.errors import DataError
from neuraldem.sim.foam_reader import (
    BoxGrid,
    FoamCase,
    cells_to_grid,
    read_cell_field,
    read_cloud_field,
    read_foam_file,
    time_dirs,
)

HEAD = """/*---*\\
| banner |
\\*---*/
FoamFile
{{
    version     2.0;
    format      {fmt};
    class       {cls};
    location    "0.1";
    object      {obj};
}}
// * * * //
"""


def foam(path: Path, cls: str, body: str, obj: str | None = None, fmt: str = "ascii") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(HEAD.format(cls=cls, obj=obj or path.name, fmt=fmt) + body)
    return path


def test_cell_fields_all_list_forms(tmp_path: Path):
    s = foam(tmp_path / "a", "volScalarField", "dimensions [0 0 0 0 0 0 0];\ninternalField nonuniform List<scalar> \n"
             "3\n(\n0.5\n0.25\n1\n)\n;\n"
             "boundaryField { top { type calculated; value nonuniform List<scalar> 2(1 2); } }\n")
    np.testing.assert_array_equal(read_cell_field(s), [0.5, 0.25, 1.0])
    inline = foam(tmp_path / "b", "volScalarField", "internalField nonuniform List<scalar> 3(0.5 0.25 1);\n")
    np.testing.assert_array_equal(read_cell_field(inline, 3), [0.5, 0.25, 1.0])
    v = foam(tmp_path / "U", "volVectorField", "internalField nonuniform List<vector> 2((1 2 3) (4 5 -6e-1));\n"
             "boundaryField { bottom { value uniform (0 0 1); } }\n")
    np.testing.assert_array_equal(read_cell_field(v), [[1, 2, 3], [4, 5, -0.6]])
    u = foam(tmp_path / "u", "volVectorField", "internalField uniform (0 0 1.5);\n")
    np.testing.assert_array_equal(read_cell_field(u, 2), [[0, 0, 1.5], [0, 0, 1.5]])
    with pytest.raises(DataError, match="uniform: pass the number of cells"):
        read_cell_field(u)
    with pytest.raises(DataError, match="has 3 cells, the mesh has 4"):
        read_cell_field(s, 4)


def test_cloud_fields_all_list_forms(tmp_path: Path):
    pos = foam(tmp_path / "positions", "Cloud<basicKinematicCollidingParcel>",
               "\n2\n(\n(0.1 0.2 0.3) 5\n(0.4 0.5 0.6) 7\n)\n\n// *** //\n")
    np.testing.assert_array_equal(read_cloud_field(pos), [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])
    ids = foam(tmp_path / "origId", "labelField", "\n2\n(\n3\n1\n)\n")
    assert read_cloud_field(ids).tolist() == [3, 1] and read_cloud_field(ids).dtype == np.int64
    proc = foam(tmp_path / "origProcId", "labelField", "2{0}\n")
    assert read_cloud_field(proc, 2).tolist() == [0, 0]
    d = foam(tmp_path / "d", "scalarField", "2{0.002}\n")
    np.testing.assert_array_equal(read_cloud_field(d), [0.002, 0.002])
    u = foam(tmp_path / "U", "vectorField", "2((1 0 0) (0 1 0))\n")
    np.testing.assert_array_equal(read_cloud_field(u), [[1, 0, 0], [0, 1, 0]])
    empty = foam(tmp_path / "e", "labelField", "0()\n")
    assert read_cloud_field(empty).shape == (0,)


def test_gzip_files_are_read(tmp_path: Path):
    text = HEAD.format(cls="labelField", obj="origId", fmt="ascii") + "3(4 5 6)\n"
    with gzip.open(tmp_path / "origId.gz", "wt") as fh:
        fh.write(text)
    assert read_cloud_field(tmp_path / "origId").tolist() == [4, 5, 6]


@pytest.mark.parametrize("body,message", [
    ("\n3\n(\n(0.1 0.2 0.3) 5\n(0.4 0.5 0.6) 7\n", "truncated"),
    ("\n3\n(\n(0.1 0.2 0.3) 5\n(0.4 0.5 0.6) 7\n)\n", "announces 3 entries of 4 value"),
    ("\n2\n(\n(0.1 0.2 0.3) 5\n(nan 0.5 0.6) 7\n)\n", "NaN or inf"),
    ("\n2\n(\n(0.1 0.2 0.3) 5\n(x 0.5 0.6) 7\n)\n", "unexpected text"),
])
def test_damaged_cloud_file_names_the_file(tmp_path: Path, body: str, message: str):
    path = foam(tmp_path / "0.3" / "positions", "Cloud<basicKinematicCollidingParcel>", body)
    with pytest.raises(DataError, match=message) as err:
        read_cloud_field(path)
    assert str(path) in str(err.value)


def test_truncated_cell_field_and_bad_headers(tmp_path: Path):
    cut = foam(tmp_path / "alpha.air", "volScalarField", "internalField nonuniform List<scalar> 4\n(\n0.5\n0.4\n")
    with pytest.raises(DataError, match="truncated"):
        read_cell_field(cut)
    binary = foam(tmp_path / "p", "volScalarField", "internalField uniform 0;\n", fmt="binary")
    with pytest.raises(DataError, match="foamFormatConvert"):
        read_cell_field(binary, 3)
    (tmp_path / "junk").write_text("hello\n")
    with pytest.raises(DataError, match="no FoamFile header"):
        read_foam_file(tmp_path / "junk")
    with pytest.raises(DataError, match="file missing"):
        read_foam_file(tmp_path / "nothing")
    wrong = foam(tmp_path / "w", "labelField", "1(3)\n")
    with pytest.raises(DataError, match="expected a volScalarField"):
        read_cell_field(wrong)


def _cloud(case: Path, time: str, ids: list[int], procs: list[int], count: int | None = None) -> None:
    d = case / time / "lagrangian" / "kinematicCloud"
    n = len(ids)
    lines = "".join(f"({i * 0.01} 0 {p * 0.01}) 0\n" for i, p in zip(ids, procs, strict=False))
    foam(d / "positions", "Cloud<x>", f"{n}\n(\n{lines})\n")
    foam(d / "origId", "labelField", f"{n}(" + " ".join(map(str, ids)) + ")\n")
    foam(d / "origProcId", "labelField", f"{n}(" + " ".join(map(str, procs)) + ")\n")
    foam(d / "d", "scalarField", f"{n}{{0.002}}\n")
    foam(d / "U", "vectorField", f"{n}{{(0 0 0)}}\n")
    if count is not None:
        foam(case / time / "uniform" / "lagrangian" / "kinematicCloud" / "cloudProperties", "dictionary",
             f"geometry coordinates;\nprocessor0 {{ particleCount {count}; }}\n")


def test_identity_is_the_pair_origprocid_origid(tmp_path: Path):
    (tmp_path / "system").mkdir()
    (tmp_path / "system" / "controlDict").write_text("")
    # a reconstructed parallel run: origId repeats across processors
    _cloud(tmp_path, "0.1", ids=[1, 0, 1, 0], procs=[1, 1, 0, 0], count=4)
    snap = FoamCase(tmp_path).cloud("0.1")
    assert list(zip(snap.orig_proc.tolist(), snap.orig_id.tolist(), strict=False)) == [(0, 0), (0, 1), (1, 0), (1, 1)]
    np.testing.assert_allclose(snap.positions[:, 0], [0.0, 0.01, 0.0, 0.01])
    np.testing.assert_allclose(snap.positions[:, 2], [0.0, 0.0, 0.01, 0.01])
    _cloud(tmp_path, "0.2", ids=[1, 1], procs=[0, 0])
    with pytest.raises(DataError, match="duplicate particle identity"):
        FoamCase(tmp_path).cloud("0.2")
    _cloud(tmp_path, "0.3", ids=[0, 1], procs=[0, 0], count=5)
    with pytest.raises(DataError, match="2 particles in the files, 5 in"):
        FoamCase(tmp_path).cloud("0.3")
    assert [name for _, name in time_dirs(tmp_path)] == ["0.1", "0.2", "0.3"]


def test_decomposed_case_asks_for_reconstructpar(tmp_path: Path):
    (tmp_path / "system").mkdir()
    (tmp_path / "system" / "controlDict").write_text("")
    (tmp_path / "0").mkdir()
    (tmp_path / "processor0" / "0.1").mkdir(parents=True)
    with pytest.raises(DataError, match="reconstructPar"):
        FoamCase(tmp_path).times()


def test_box_grid_mapping():
    g = BoxGrid((0, 0, 0), (3.0, 1.0, 2.0), (3, 1, 2))
    flat = np.array([[x + 0.5, 0.5, z + 0.5] for z in range(2) for x in range(3)])  # blockMesh order
    idx, how = cells_to_grid(flat, g)
    assert how == "exact"
    np.testing.assert_allclose(flat[idx], g.centres())
    np.testing.assert_allclose(g.to_grid(flat), g.centres())
    shuffled = flat[::-1]
    idx, how = cells_to_grid(shuffled, g)
    assert how == "exact"
    np.testing.assert_allclose(shuffled[idx], g.centres())
    _, how = cells_to_grid(flat + 0.1, g)
    assert how == "nearest"


@pytest.mark.solver
def test_real_case_reads_consistently(fb_tiny_case: Path):
    case = FoamCase(fb_tiny_case)
    times = case.times()
    assert times[0] == (0.0, "0") and len(times) == 26  # 0 .. 0.25 every 0.01 s
    grid = BoxGrid((0, 0, 0), (0.024, 0.006, 0.06), (6, 1, 15))
    _, how = cells_to_grid(case.cell_centres(), grid)
    assert how == "exact" and case.n_cells == 90
    for _, name in times[1:]:
        assert case.check_time(name) is None
        snap = case.cloud(name)
        assert len(snap) == 300 == case.particle_count(name)
        assert case.escaped_parcels(name) == 0
        lo, hi = np.zeros(3), np.array([0.024, 0.006, 0.06])
        assert np.all(snap.positions >= lo) and np.all(snap.positions <= hi)
        np.testing.assert_allclose(snap.diameters, 0.002)
        alpha = case.cell_field(name, "fluid_fraction")
        # DPMFoam's alpha bins the particle volume by cell: it holds exactly the particles' volume
        solid = (1 - alpha).sum() * grid.cell_volume
        assert solid == pytest.approx(300 * np.pi / 6 * 0.002**3, rel=1e-6)
        assert case.cell_field(name, "fluid_velocity").shape == (90, 3)
