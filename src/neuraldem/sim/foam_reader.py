"""Readers for the ASCII output of OpenFOAM's particle solvers (DPMFoam, MPPICFoam; v1912 layout).

What they read, per time directory of a (serial or reconstructed) case:
  cell fields   <time>/alpha.air, <time>/U.air, <time>/p           internalField, uniform or nonuniform
  cell centres  <time>/C (written by `postProcess -func writeCellCentres`)
  particles     <time>/lagrangian/<cloud>/{positions, origId, origProcId, d, U}
  bookkeeping   <time>/uniform/lagrangian/<cloud>/cloudProperties (particle count per processor) and
                <cloud>OutputProperties (parcels that escaped through a patch)

Every reader validates what it reads: the FoamFile header (class, ASCII format), the announced list length
against the values found (a file cut short by a killed run or a full disk is an error, never a shorter
array), finite values, and the same particle count in every file of a cloud. Errors are DataErrors naming
the file and the field. Files written with `writeCompression on` (`*.gz`) are read transparently.

Particle identity: a particle is the pair (origProcId, origId); origId alone repeats across processors in
parallel runs. Snapshots come back sorted by that pair.
"""

from __future__ import annotations

import gzip
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neuraldem.errors import DataError

BINARY_FIX = ("convert the case to ASCII: set `writeFormat ascii;` in system/controlDict and run "
              "`foamFormatConvert` in the case folder")
_COMMENTS = re.compile(r"/\*.*?\*/|//[^\n]*", re.DOTALL)


@dataclass
class FoamFile:
    path: Path
    header: dict[str, str]
    body: str  # text after the FoamFile header, comments removed

    @property
    def cls(self) -> str:
        return self.header.get("class", "")


def resolve(path: Path) -> Path | None:
    """`path`, or its gzip-compressed twin `path.gz`; None if neither exists."""
    path = Path(path)
    if path.is_file():
        return path
    gz = path.with_name(path.name + ".gz")
    return gz if gz.is_file() else None


def read_foam_file(path: Path) -> FoamFile:
    """Header + body of an ASCII OpenFOAM file; DataError for missing, binary or header-less files."""
    found = resolve(path)
    if found is None:
        raise DataError(f"{path}: file missing (an incomplete time directory?)")
    try:
        if found.suffix == ".gz":
            with gzip.open(found, "rt", errors="replace") as fh:
                text = fh.read()
        else:
            text = found.read_text(errors="replace")
    except (OSError, EOFError) as err:  # EOFError: a truncated .gz
        raise DataError(f"{found}: unreadable ({err}); the file is damaged or truncated") from None
    text = _COMMENTS.sub(" ", text)
    start = text.find("FoamFile")
    open_ = text.find("{", start)
    close = text.find("}", open_)
    if start < 0 or open_ < 0 or close < 0:
        raise DataError(f"{found}: no FoamFile header: not an OpenFOAM file, or empty (a killed write?)")
    header = {}
    for entry in text[open_ + 1:close].split(";"):
        parts = entry.split(None, 1)
        if len(parts) == 2:
            header[parts[0]] = parts[1].strip().strip('"')
    if header.get("format", "ascii") != "ascii":
        raise DataError(f"{found}: written in {header.get('format')!r} format, neuraldem reads ASCII", fix=BINARY_FIX)
    return FoamFile(found, header, text[close + 1:])


def _numbers(text: str, where: str) -> np.ndarray:
    try:
        return np.array(text.replace("(", " ").replace(")", " ").split(), dtype=np.float64)
    except ValueError as err:
        raise DataError(f"{where}: unexpected text in a list of numbers ({err})") from None


def _components(type_name: str, where: str) -> int:
    if type_name in ("scalar", "label"):
        return 1
    if type_name == "vector":
        return 3
    raise DataError(f"{where}: list of {type_name!r} (neuraldem reads scalar, label and vector fields)")


def _parse_list(text: str, ncomp: int, where: str, semicolon: bool) -> tuple[np.ndarray, int]:
    """`N ( ... )`, `N(...)` or `N{value}` at the start of `text`; returns (values (N, ncomp), end offset).
    `semicolon`: the list is followed by ';' (a field entry), else it runs to the end of `text` (lagrangian)."""
    m = re.match(r"\s*(\d+)\s*([({])", text)
    if m is None:
        raise DataError(f"{where}: expected a list `N ( ... )`, found {text.strip()[:30]!r}")
    n = int(m.group(1))
    if m.group(2) == "{":
        close = text.find("}", m.end())
        if close < 0:
            raise DataError(f"{where}: uniform list `{n}{{...` is not closed (truncated file)")
        value = _numbers(text[m.end():close], where)
        if value.size != ncomp:
            raise DataError(f"{where}: uniform value has {value.size} components, expected {ncomp}")
        return np.tile(value, (n, 1)), close + 1
    # the closing parenthesis of the list: before ';' for fields, the last one for lagrangian files
    if semicolon:
        close = re.compile(r"\)\s*;").search(text, m.end())
        end = close.start() if close else -1
    else:
        end = text.rfind(")")
        end = end if end >= m.end() else -1
    if end < 0:
        raise DataError(f"{where}: the list of {n} values is not closed: the file is truncated (a killed run "
                        "or a full disk?)")
    values = _numbers(text[m.end():end], where)
    if values.size != n * ncomp:
        raise DataError(f"{where}: announces {n} entries of {ncomp} value(s) but holds {values.size} values "
                        "(truncated or damaged file)")
    return values.reshape(n, ncomp), end + 1


def read_cell_field(path: Path, n_cells: int | None = None) -> np.ndarray:
    """internalField of a volScalarField (-> (n,)) or volVectorField (-> (n, 3)), uniform or nonuniform.
    A uniform field needs `n_cells` to expand."""
    f = read_foam_file(path)
    where = f"{f.path}: internalField"
    if f.cls not in ("volScalarField", "volVectorField"):
        raise DataError(f"{f.path}: class {f.cls!r}, expected a volScalarField or volVectorField (cell field)")
    ncomp = 1 if f.cls == "volScalarField" else 3
    m = re.search(r"\binternalField\s+(uniform|nonuniform)\b", f.body)
    if m is None:
        raise DataError(f"{where} is missing (truncated file?)")
    rest = f.body[m.end():]
    if m.group(1) == "uniform":
        semi = rest.find(";")
        value = _numbers(rest[:semi] if semi >= 0 else "", where)
        if value.size != ncomp:
            raise DataError(f"{where}: uniform value with {value.size} components, expected {ncomp}")
        if n_cells is None:
            raise DataError(f"{where} is uniform: pass the number of cells to expand it")
        values = np.tile(value, (n_cells, 1))
    else:
        lm = re.match(r"\s*List<(\w+)>", rest)
        if lm is None:
            raise DataError(f"{where}: expected `nonuniform List<type>`")
        _components(lm.group(1), where)
        values, _ = _parse_list(rest[lm.end():], ncomp, where, semicolon=True)
    if n_cells is not None and len(values) != n_cells:
        raise DataError(f"{where} has {len(values)} cells, the mesh has {n_cells}")
    if not np.isfinite(values).all():
        raise DataError(f"{where} holds NaN or inf values (a diverged run?)")
    return values[:, 0] if ncomp == 1 else values


_CLOUD_CLASSES = {"labelField": 1, "scalarField": 1, "vectorField": 3}


def read_cloud_field(path: Path, n: int | None = None) -> np.ndarray:
    """One lagrangian field: labelField/scalarField -> (n,), vectorField -> (n, 3), `positions`
    (class Cloud<...>, entries `(x y z) celli`) -> (n, 3) coordinates."""
    f = read_foam_file(path)
    where = f"{f.path}"
    if f.cls.startswith("Cloud<"):
        ncomp = 4
    elif f.cls in _CLOUD_CLASSES:
        ncomp = _CLOUD_CLASSES[f.cls]
    else:
        raise DataError(f"{where}: class {f.cls!r} is not a lagrangian field neuraldem reads")
    values, end = _parse_list(f.body, ncomp, where, semicolon=False)
    if f.body[end:].strip():
        raise DataError(f"{where}: unexpected text after the list: {f.body[end:].strip()[:30]!r}")
    if n is not None and len(values) != n:
        raise DataError(f"{where}: {len(values)} particles, expected {n} like the other files of this cloud")
    if not np.isfinite(values).all():
        raise DataError(f"{where}: NaN or inf values (a diverged run?)")
    if ncomp == 4:
        return values[:, :3]
    if f.cls == "labelField":
        if np.any(values != np.round(values)):
            raise DataError(f"{where}: non-integer labels")
        return values[:, 0].astype(np.int64)
    return values[:, 0] if ncomp == 1 else values


def read_dict_entries(path: Path) -> dict[str, str]:
    """Flat `key value;` entries of a dictionary file (nested braces are flattened away)."""
    f = read_foam_file(path)
    out = {}
    for m in re.finditer(r"(\w+)\s+([^;{}]+);", f.body):
        out.setdefault(m.group(1), m.group(2).strip())
    return out


def mesh_bounds(case: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """Bounding box (lo, hi) of the mesh points in constant/polyMesh/points; None if there is no such file."""
    path = Path(case) / "constant" / "polyMesh" / "points"
    if resolve(path) is None:
        return None
    pts = read_cloud_field(path)
    return pts.min(axis=0), pts.max(axis=0)


# ---- case layout


def is_time_name(name: str) -> bool:
    try:
        return math.isfinite(float(name))
    except ValueError:
        return False


def time_dirs(case: Path) -> list[tuple[float, str]]:
    """(value, name) of every time directory of a case, sorted by value."""
    case = Path(case)
    out = [(float(p.name), p.name) for p in case.iterdir() if p.is_dir() and is_time_name(p.name)]
    return sorted(out)


@dataclass
class CloudSnapshot:
    """Particles of one time directory, sorted by (orig_proc, orig_id)."""

    orig_proc: np.ndarray  # (N,) int64
    orig_id: np.ndarray  # (N,) int64
    positions: np.ndarray  # (N, 3) [m]
    velocities: np.ndarray | None  # (N, 3) [m/s]
    diameters: np.ndarray  # (N,) [m]

    def __len__(self) -> int:
        return len(self.orig_id)

    @property
    def keys(self) -> np.ndarray:
        return particle_keys(self.orig_proc, self.orig_id)


def particle_keys(orig_proc: np.ndarray, orig_id: np.ndarray) -> np.ndarray:
    """One int64 per particle that sorts like the pair (origProcId, origId)."""
    return (np.asarray(orig_proc, dtype=np.int64) << 32) + np.asarray(orig_id, dtype=np.int64)


class FoamCase:
    """A serial or reconstructed OpenFOAM case with a particle cloud.

    `fluid_fraction` and `fluid_velocity` name the continuous-phase fields (DPMFoam/MPPICFoam with
    `continuousPhase air`: alpha.air and U.air; CFDEM: voidfraction and U)."""

    def __init__(self, path: Path, cloud: str = "kinematicCloud", fluid_fraction: str = "alpha.air",
                 fluid_velocity: str = "U.air", pressure: str = "p"):
        self.path = Path(path)
        if not self.path.is_dir():
            raise DataError(f"OpenFOAM case {self.path} does not exist")
        if not (self.path / "system" / "controlDict").is_file():
            raise DataError(f"{self.path} is not an OpenFOAM case (no system/controlDict)")
        self.cloud_name = cloud
        self.fields = {"fluid_fraction": fluid_fraction, "fluid_velocity": fluid_velocity, "pressure": pressure}
        self._centres: np.ndarray | None = None

    # ---- layout
    def times(self) -> list[tuple[float, str]]:
        t = time_dirs(self.path)
        if not any(self.has_cloud(name) for _, name in t) and any(self.path.glob("processor*")):
            raise DataError(f"{self.path} is decomposed (processor* folders, no particles in its own time "
                            "directories)", fix="run `reconstructPar` in the case folder first (it keeps the "
                            "particles' origProcId/origId identity)")
        return t

    def cloud_dir(self, time_name: str) -> Path:
        return self.path / time_name / "lagrangian" / self.cloud_name

    def has_cloud(self, time_name: str) -> bool:
        return resolve(self.cloud_dir(time_name) / "positions") is not None

    # ---- mesh
    def cell_centres(self) -> np.ndarray:
        """(n_cells, 3) from the first time directory (or constant/) holding `C`."""
        if self._centres is None:
            places = [name for _, name in time_dirs(self.path)] + ["constant"]
            for name in places:
                if resolve(self.path / name / "C") is not None:
                    self._centres = read_cell_field(self.path / name / "C")
                    break
            else:
                raise DataError(f"{self.path}: no cell centres (C) in any time directory",
                                fix="run `postProcess -func writeCellCentres -time 0` in the case folder")
        return self._centres

    @property
    def n_cells(self) -> int:
        return len(self.cell_centres())

    # ---- fields
    def cell_field(self, time_name: str, which: str) -> np.ndarray:
        return read_cell_field(self.path / time_name / self.fields[which], self.n_cells)

    def cloud(self, time_name: str, velocities: bool = True) -> CloudSnapshot:
        d = self.cloud_dir(time_name)
        pos = read_cloud_field(d / "positions")
        n = len(pos)
        oid = read_cloud_field(d / "origId", n)
        proc = read_cloud_field(d / "origProcId", n)
        diam = read_cloud_field(d / "d", n)
        if oid.ndim != 1 or proc.ndim != 1 or diam.ndim != 1 or pos.ndim != 2:
            raise DataError(f"{d}: origId, origProcId and d must be scalar lists, positions a vector list")
        vel = read_cloud_field(d / "U", n) if velocities else None
        expected = self.particle_count(time_name)
        if expected is not None and expected != n:
            raise DataError(f"{d}: {n} particles in the files, {expected} in uniform/lagrangian/{self.cloud_name}/"
                            "cloudProperties (an incomplete write?)")
        keys = particle_keys(proc, oid)
        order = np.argsort(keys, kind="stable")
        if np.any(np.diff(keys[order]) == 0):
            raise DataError(f"{d}: duplicate particle identity (origProcId, origId)")
        if np.any(diam <= 0):
            raise DataError(f"{d}/d: non-positive particle diameters")
        return CloudSnapshot(orig_proc=proc[order], orig_id=oid[order], positions=pos[order],
                             velocities=None if vel is None else vel[order], diameters=diam[order])

    def _cloud_props(self, time_name: str, suffix: str) -> Path | None:
        return resolve(self.path / time_name / "uniform" / "lagrangian" / self.cloud_name / suffix)

    def particle_count(self, time_name: str) -> int | None:
        """Sum of `particleCount` over processors in cloudProperties (None where absent)."""
        p = self._cloud_props(time_name, "cloudProperties")
        if p is None:
            return None
        counts = re.findall(r"particleCount\s+(\d+)\s*;", read_foam_file(p).body)
        return sum(int(c) for c in counts) if counts else None

    def escaped_parcels(self, time_name: str) -> int | None:
        """Parcels that left through a patch so far (the cloud's OutputProperties); None where absent."""
        p = self._cloud_props(time_name, f"{self.cloud_name}OutputProperties")
        if p is None:
            return None
        m = re.search(r"escapedParcels\s+(\d+)\s*;", read_foam_file(p).body)
        return int(m.group(1)) if m else None

    def check_time(self, time_name: str, with_pressure: bool = True) -> str | None:
        """None when the time directory is complete and readable, else the reason."""
        try:
            self.cell_field(time_name, "fluid_fraction")
            self.cell_field(time_name, "fluid_velocity")
            if with_pressure:
                self.cell_field(time_name, "pressure")
            if not self.has_cloud(time_name):
                return f"{self.cloud_dir(time_name)}: no particles"
            self.cloud(time_name)
        except DataError as err:
            return str(err)
        return None


# ---- the regular grid the datasets store cell data on


@dataclass(frozen=True)
class BoxGrid:
    """A regular grid of shape (nx, ny, nz) over the box [lo, hi]; cell (i, j, k) is flat index
    i + nx * (j + ny * k), the order blockMesh numbers the cells of a single hex block."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    shape: tuple[int, int, int]

    @property
    def spacing(self) -> np.ndarray:
        return (np.asarray(self.hi) - np.asarray(self.lo)) / np.asarray(self.shape)

    @property
    def cell_volume(self) -> float:
        return float(np.prod(self.spacing))

    @property
    def n_cells(self) -> int:
        return int(np.prod(self.shape))

    def edges(self, axis: int) -> np.ndarray:
        return np.linspace(self.lo[axis], self.hi[axis], self.shape[axis] + 1)

    def axis_centres(self, axis: int) -> np.ndarray:
        e = self.edges(axis)
        return 0.5 * (e[1:] + e[:-1])

    def centres(self) -> np.ndarray:
        """(nx, ny, nz, 3) cell centres."""
        x, y, z = (self.axis_centres(a) for a in range(3))
        return np.stack(np.meshgrid(x, y, z, indexing="ij"), axis=-1)

    def to_grid(self, flat: np.ndarray) -> np.ndarray:
        """Flat blockMesh-ordered cell values (n_cells, ...) -> (nx, ny, nz, ...)."""
        nx, ny, nz = self.shape
        return np.moveaxis(flat.reshape(nz, ny, nx, *flat.shape[1:]), (0, 1, 2), (2, 1, 0))

    def as_dict(self) -> dict[str, list[float] | list[int]]:
        return {"lo": list(self.lo), "hi": list(self.hi), "shape": list(self.shape)}


def cells_to_grid(centres: np.ndarray, grid: BoxGrid, rtol: float = 1e-6) -> tuple[np.ndarray, str]:
    """For each grid cell, the index of the mesh cell that supplies its value: (nx, ny, nz) int array and
    the method: 'exact' when the mesh cell centres are the grid's (a blockMesh box, any cell order),
    else 'nearest' (the mesh cell whose centre is nearest to the grid cell centre)."""
    from scipy.spatial import cKDTree

    target = grid.centres().reshape(-1, 3)
    dist, idx = cKDTree(centres).query(target)
    tol = rtol * float(np.max(np.asarray(grid.hi) - np.asarray(grid.lo)))
    exact = len(centres) == grid.n_cells and bool(np.all(dist <= tol)) and len(np.unique(idx)) == grid.n_cells
    return idx.reshape(grid.shape), "exact" if exact else "nearest"
