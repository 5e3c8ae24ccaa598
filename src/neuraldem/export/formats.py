"""Particle trajectories in the file formats of two other learned-simulator tools, written and read back.

Both formats hold, per split, trajectories of a fixed particle set: positions (T, N, D) and a type per
particle (N,), with a `metadata.json` beside them that the tools read (bounds, connectivity radius, dt, the
velocity and acceleration statistics they normalise with). Velocities and accelerations in those statistics
are per snapshot step, as the tools compute them from positions (v = x_t - x_{t-1}, a = v_{t+1} - v_t, in
metres per step and per step^2), not per second. `sequence_length` counts steps: a trajectory of T snapshots
has T - 1.

- "gns": DeepMind's learning_to_simulate datasets converted to npz, as read by the PyTorch `gns` package
  (`gns/data_loader.py`, `load_npz_data`): `train.npz`, `valid.npz`, `test.npz`, each a zip of one entry per
  trajectory holding an object array `(positions float32 (T, N, D), particle_type int (N,))`, or with a third
  element, one material-property number per trajectory (a conditioning scalar the package feeds every
  particle). Reading needs `np.load(..., allow_pickle=True)`. Trajectory lengths may differ.
- "lagrangebench": LagrangeBench's `H5Dataset` (`lagrangebench/data/data.py`): `train.h5`, `valid.h5`,
  `test.h5` with one group per trajectory named 00000, 00001, ... holding `position` float32 (T, N, D) and
  `particle_type` (N,). The reader takes the length of trajectory 00000 for all of a split, so every
  trajectory of a split is cut to the split's shortest; particle counts that differ are padded at the end to
  `num_particles_max` with type -1 (LagrangeBench's padding type, treated as fixed) at the origin.

Coordinates are metres relative to the lower corner of `bounds` (that corner is 0; the offset is
`neuraldem.origin` in the metadata): LagrangeBench's neighbour search bins positions in [0, box]. Every
moving particle has type 0 (free material in both tools: neither GNS's kinematic 3 nor LagrangeBench's walls
1 and 2).

Particles that leave (a hopper's sink, particles a CFD-DEM solver lost) cannot leave a fixed particle set; the
exporter applies one of `EXIT_RULES` and records it. With "hold" an exited particle stays at its last
position, and `exit_step_<split>.npz` (one int array per trajectory: the first snapshot at which each particle
is gone, T = never) lets `read_export` give them back as NaN.

Besides the keys each tool reads, `metadata.json` has a `neuraldem` section: the source dataset, kind, scene,
split, exit rule, origin, particle diameter, and per trajectory its simulation id, conditioning scalars and
lengths. `read_export` reads both formats back into `Trajectory` arrays (the round trip the tests check, and
what `ExportGnsDataModule` trains from).
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from neuraldem.errors import DataError

FORMATS = ("gns", "lagrangebench")
SUFFIX = {"gns": "npz", "lagrangebench": "h5"}
PARTS = {"train": "train", "val": "valid", "test": "test"}  # our split part -> the formats' file name
EXIT_RULES = ("refuse", "truncate", "hold")
MATERIAL = 0  # the type of every exported particle
PAD = -1  # LagrangeBench's padding type
METADATA = "metadata.json"
FORMAT_VERSION = 1
MIN_SNAPSHOTS = 3  # one acceleration: the least a trajectory must keep


@dataclass
class Trajectory:
    """One exported trajectory: positions as stored (float32, relative to the export's origin; exited
    particles held at their last position), types, and when each particle left (`exit_step`, the first
    snapshot it is gone; T = never)."""

    sim_id: str
    positions: np.ndarray  # (T, N, D) float32
    particle_type: np.ndarray  # (N,) int
    exit_step: np.ndarray  # (N,) int
    conditioning: dict[str, float] = field(default_factory=dict)

    @property
    def n_snapshots(self) -> int:
        return int(self.positions.shape[0])

    def present(self, t: slice = slice(None)) -> np.ndarray:
        """(T', N) True where a particle is there (not yet exited, not padding)."""
        steps = np.arange(self.n_snapshots)[t]
        return (steps[:, None] < self.exit_step[None]) & (self.particle_type != PAD)[None]

    def physical(self, t: slice = slice(None)) -> np.ndarray:
        """Positions (T', N, D) float64 with NaN where a particle is not there (as the datasets store them)."""
        x = self.positions[t].astype(np.float64)
        x[~self.present(t)] = np.nan
        return x


# ---- the exit rules
def exit_steps(x: np.ndarray) -> np.ndarray:
    """(N,) the first snapshot at which each particle of positions (T, N, D) (NaN = gone; none reappears) is
    gone, T for those that never leave."""
    return np.isfinite(x).all(axis=-1).sum(axis=0)


def kept_length(exit_step: np.ndarray, n_snapshots: int, rule: str) -> int:
    """Snapshots a trajectory keeps under an exit rule ("refuse" keeps all; the caller refuses)."""
    return int(min(exit_step.min(), n_snapshots)) if rule == "truncate" else n_snapshots


def apply_exit_rule(x: np.ndarray, rule: str) -> tuple[np.ndarray, np.ndarray]:
    """Positions (T', N, D) float64 without NaN and each particle's exit step under `rule`: "truncate" keeps
    the snapshots before the first exit, "hold" keeps every snapshot with a gone particle at its last
    position. ("refuse" is the caller's check; here it keeps everything, so the run must have no exit.)"""
    exit_step = exit_steps(x)
    t_keep = kept_length(exit_step, len(x), rule)
    x = np.array(x[:t_keep], dtype=np.float64)
    exit_step = np.minimum(exit_step, t_keep)
    if rule == "hold":
        gone = np.arange(t_keep)[:, None] >= exit_step[None]
        last = x[np.maximum(exit_step - 1, 0), np.arange(x.shape[1])]
        x = np.where(gone[..., None], last[None], x)
    if not np.isfinite(x).all():
        raise ValueError("positions keep NaN after the exit rule (a particle missing at the first snapshot?)")
    return x, exit_step


# ---- statistics
@dataclass
class Moments:
    """Per-axis count, mean and sum of squared deviations, merged trajectory by trajectory (Chan et al.), so
    the statistics of a large split need no more memory than one trajectory."""

    n: int = 0
    mean: np.ndarray | None = None
    m2: np.ndarray | None = None

    def add(self, values: np.ndarray) -> None:
        if not len(values):
            return
        n_b, mean_b = len(values), values.mean(axis=0)
        m2_b = ((values - mean_b) ** 2).sum(axis=0)
        if self.mean is None or self.m2 is None:
            self.n, self.mean, self.m2 = n_b, mean_b, m2_b
            return
        n = self.n + n_b
        delta = mean_b - self.mean
        self.mean = self.mean + delta * n_b / n
        self.m2 = self.m2 + m2_b + delta**2 * self.n * n_b / n
        self.n = n

    def std(self) -> np.ndarray:
        assert self.m2 is not None
        s = np.sqrt(self.m2 / self.n)
        return np.where(s > 0, s, 1.0)  # a channel that never varies is left unscaled


def step_values(traj: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Per-step velocities (M, D) and accelerations (K, D) [m/step, m/step^2] of the particles present at
    every snapshot involved, from the stored (float32) positions."""
    x = traj.positions.astype(np.float64)
    ok = traj.present()
    v = (x[1:] - x[:-1])[ok[1:] & ok[:-1]]
    a = (x[2:] - 2 * x[1:-1] + x[:-2])[ok[2:] & ok[1:-1] & ok[:-2]]
    return v, a


class StepStatistics:
    """vel_mean, vel_std, acc_mean, acc_std of the trajectories added (the training split's)."""

    def __init__(self) -> None:
        self.v, self.a = Moments(), Moments()

    def add(self, traj: Trajectory) -> None:
        v, a = step_values(traj)
        self.v.add(v)
        self.a.add(a)

    def to_dict(self) -> dict[str, list[float]]:
        if self.a.n == 0:
            raise DataError(f"the training split has no particle with {MIN_SNAPSHOTS} consecutive snapshots: "
                            "nothing to compute the acceleration statistics from")
        assert self.v.mean is not None and self.a.mean is not None
        return {"vel_mean": self.v.mean.tolist(), "vel_std": self.v.std().tolist(),
                "acc_mean": self.a.mean.tolist(), "acc_std": self.a.std().tolist()}


# ---- metadata
def tool_metadata(fmt: str, *, dim: int, dt: float, bounds: np.ndarray, radius: float, diameter: float,
                  case: str, solver: str, lengths: dict[str, list[int]], n_particles_max: int,
                  stats: dict[str, list[float]], material_property: bool) -> dict[str, Any]:
    """The keys the tool of `fmt` reads (lengths: snapshots of each exported trajectory, per part)."""
    out: dict[str, Any] = {"bounds": np.asarray(bounds).tolist(), "dim": dim, "dt": dt,
                           "default_connectivity_radius": radius}
    every = [n for ns in lengths.values() for n in ns]
    if fmt == "gns":
        # the shortest trajectory's steps: the `gns` package rolls every test trajectory out for this many
        out["sequence_length"] = min(every) - 1
        # node inputs of the package's default net: 5 velocities, 2 D wall distances, a 16-wide type
        # embedding, and the material property when there is one
        out["nnode_in"] = 5 * dim + 2 * dim + 16 + int(material_property)
        out["nedge_in"] = dim + 1
    else:
        out.update(case=case, solver=solver, dx=diameter, t_end=dt * (max(every) - 1), write_every=1,
                   num_particles_max=n_particles_max, periodic_boundary_conditions=[False] * dim)
        for part, stem in PARTS.items():  # LagrangeBench reads the _train and _test ones
            out[f"sequence_length_{stem}"] = (lengths[part][0] - 1) if lengths[part] else 0
            out[f"num_trajs_{stem}"] = len(lengths[part])
    return {**out, **stats}


def trajectory_key(fmt: str, i: int) -> str:
    return f"{i:05d}" if fmt == "lagrangebench" else f"trajectory_{i:05d}"


# ---- writing
class SplitWriter:
    """Writes one split file of either format trajectory by trajectory (memory: one trajectory), and the
    exit steps beside it when an exit rule holds particles."""

    def __init__(self, folder: Path, fmt: str, part: str, material: str | None, n_pad: int | None,
                 write_exits: bool):
        self.fmt, self.material, self.n_pad = fmt, material, n_pad
        self.path = Path(folder) / f"{PARTS[part]}.{SUFFIX[fmt]}"
        self.exits_path = Path(folder) / f"exit_step_{PARTS[part]}.npz" if write_exits else None
        self.count = 0
        self._exits: dict[str, np.ndarray] = {}
        if fmt == "gns":
            self._zip: zipfile.ZipFile | None = zipfile.ZipFile(self.path, "w", zipfile.ZIP_DEFLATED,
                                                                allowZip64=True)
            self._h5: h5py.File | None = None
        else:
            self._zip, self._h5 = None, h5py.File(self.path, "w")

    def add(self, traj: Trajectory) -> str:
        key = trajectory_key(self.fmt, self.count)
        self.count += 1
        pos, types, exit_step = traj.positions.astype(np.float32), traj.particle_type, traj.exit_step
        if self.n_pad is not None and pos.shape[1] < self.n_pad:
            extra = self.n_pad - pos.shape[1]
            pos = np.concatenate([pos, np.zeros((pos.shape[0], extra, pos.shape[2]), np.float32)], axis=1)
            types = np.concatenate([types, np.full(extra, PAD, dtype=types.dtype)])
            exit_step = np.concatenate([exit_step, np.zeros(extra, dtype=exit_step.dtype)])
        if self._zip is not None:
            entry = np.empty(3 if self.material else 2, dtype=object)
            entry[0], entry[1] = pos, types.astype(np.int64)
            if self.material:
                entry[2] = float(traj.conditioning[self.material])
            with self._zip.open(f"{key}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, entry, allow_pickle=True)
        else:
            assert self._h5 is not None
            g = self._h5.create_group(key)
            g.create_dataset("position", data=pos, compression="gzip")
            g.create_dataset("particle_type", data=types.astype(np.int64))
        if self.exits_path is not None:
            self._exits[key] = exit_step.astype(np.int32)
        return key

    def close(self) -> None:
        if self._zip is not None:
            self._zip.close()
        if self._h5 is not None:
            self._h5.close()
        if self.exits_path is not None:
            np.savez_compressed(self.exits_path, **self._exits)


# ---- reading
@dataclass
class Export:
    folder: Path
    metadata: dict[str, Any]
    parts: dict[str, list[Trajectory]]

    @property
    def info(self) -> dict[str, Any]:
        return self.metadata["neuraldem"]

    @property
    def format(self) -> str:
        return str(self.info["format"])

    @property
    def kind(self) -> str:
        return str(self.info["kind"])

    @property
    def box(self) -> tuple[np.ndarray, np.ndarray]:
        b = np.asarray(self.metadata["bounds"], dtype=np.float64)
        return b[:, 0], b[:, 1]


def read_metadata(folder: Path) -> dict[str, Any]:
    path = Path(folder) / METADATA
    if not Path(folder).is_dir():
        raise DataError(f"no export at {folder}: write one with `neuraldem export gns DATASET {folder}`")
    try:
        meta = json.loads(path.read_text())
    except FileNotFoundError:
        raise DataError(f"{folder} has no {METADATA}: not an export (write one with `neuraldem export`)") from None
    except json.JSONDecodeError as err:
        raise DataError(f"{path} is not valid JSON ({err})", "export the dataset again") from None
    info = meta.get("neuraldem") if isinstance(meta, dict) else None
    if not isinstance(info, dict) or info.get("format") not in FORMATS:
        raise DataError(f"{path} has no 'neuraldem' section naming the format: not written by `neuraldem export`")
    if info.get("format_version") != FORMAT_VERSION:
        raise DataError(f"{path}: export format version {info.get('format_version')}, this neuraldem reads "
                        f"{FORMAT_VERSION}", "export the dataset again")
    return meta


def _split_entries(path: Path, fmt: str) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
    """(key, positions, particle_type) of every trajectory in one split file, in file order."""
    try:
        if fmt == "gns":
            with np.load(path, allow_pickle=True) as z:  # the format is pickled object arrays
                for key in z.files:
                    entry = z[key]
                    yield key, np.asarray(entry[0]), np.asarray(entry[1])
        else:
            with h5py.File(path, "r") as f:
                for key in f:
                    yield key, f[key]["position"][()], f[key]["particle_type"][()]
    except FileNotFoundError:
        raise DataError(f"{path} is missing: export the dataset again") from None
    except (OSError, KeyError, IndexError, ValueError, zipfile.BadZipFile) as err:
        raise DataError(f"{path} is unreadable or not of the {fmt} layout ({type(err).__name__}: {err})",
                        "export the dataset again") from None


def read_export(folder: Path) -> Export:
    """Every trajectory of an export (either format) as written: float32 positions relative to the origin,
    padding removed, exit steps from the exit files (T where there are none)."""
    folder = Path(folder)
    meta = read_metadata(folder)
    info = meta["neuraldem"]
    fmt = info["format"]
    parts: dict[str, list[Trajectory]] = {}
    for part, stem in PARTS.items():
        records = info["trajectories"].get(part, [])
        parts[part] = []
        if not records:
            continue
        exits_path = folder / f"exit_step_{stem}.npz"
        exits = dict(np.load(exits_path)) if exits_path.is_file() else {}
        path = folder / f"{stem}.{SUFFIX[fmt]}"
        entries = list(_split_entries(path, fmt))
        if len(entries) != len(records):
            raise DataError(f"{path} holds {len(entries)} trajectories, {METADATA} lists {len(records)}",
                            "export the dataset again")
        for (key, pos, types), rec in zip(entries, records, strict=True):
            if pos.ndim != 3 or types.shape != (pos.shape[1],):
                raise DataError(f"{path}: trajectory {key} has positions {pos.shape} and types {types.shape}, "
                                "expected (T, N, D) and (N,)")
            t = pos.shape[0]
            exit_step = exits.get(key, np.full(len(types), t)).astype(np.int64)
            real = types != PAD
            parts[part].append(Trajectory(sim_id=str(rec["sim_id"]), positions=pos[:, real],
                                          particle_type=types[real].astype(np.int64), exit_step=exit_step[real],
                                          conditioning={k: float(v) for k, v in rec["conditioning"].items()}))
    return Export(folder, meta, parts)


def trajectories_of(export: Export, parts: Iterable[str]) -> list[Trajectory]:
    return [t for p in parts for t in export.parts[p]]
