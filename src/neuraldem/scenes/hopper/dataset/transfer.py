"""Compact copies of a hopper dataset for moving it to a training machine.

`pack` keeps what training and evaluation read (particle ids, exit times, snapshot times, quantised
positions, geometry, the manifest) and drops the velocities. Positions are stored exactly: the first
snapshot as is, then per-particle differences to the previous snapshot (zero for material at rest), byte-
shuffled and LZMA-compressed, about 3x smaller than the HDF5 files. Simulations are grouped into part
folders of at most `max_part_mb` so that each part fits one transfer. `unpack` rebuilds HDF5 files of the
normal schema (without /snapshots/velocity) and the manifest, with each record's checksum updated to the
rebuilt file; scene, parameters, metrics and splits are unchanged, so a model trained on the copy evaluates
on the original.

    neuraldem export pack dataset=DATASET_DIR out=OUT_DIR [max_part_mb=60]
    neuraldem export unpack parts=[OUT_DIR/part_000,OUT_DIR/part_001] dataset=NEW_DATASET_DIR
"""

from __future__ import annotations

import json
import lzma
import shutil
import sys
from pathlib import Path

import h5py
import numpy as np

from neuraldem.cli import doc_parser, report_user_errors
from neuraldem.data.integrity import command_line, dataset_lock
from neuraldem.data.manifest import MANIFEST_NAME, Manifest
from neuraldem.data.schema import atomic_write_json, sha256
from neuraldem.errors import DataError
from neuraldem.scenes.hopper.dataset.store import MISSING, HopperFile, write_hopper_file
from neuraldem.scenes.hopper.solver import HopperGeometry, HopperTrajectory


def _shuffle(a: np.ndarray) -> bytes:
    """Byte planes one after the other: the zero high bytes of small numbers compress to nothing."""
    return a.view(np.uint8).reshape(-1, a.itemsize).T.tobytes()


def _unshuffle(b: bytes, dtype: np.dtype, n: int) -> np.ndarray:
    planes = np.frombuffer(b, dtype=np.uint8).reshape(np.dtype(dtype).itemsize, n)
    return np.ascontiguousarray(planes.T).view(dtype).reshape(n)


def encode_positions(q: np.ndarray) -> tuple[np.ndarray, bytes]:
    """(T, N, 3) int16 with MISSING -> (present mask bits, compressed first frame + deltas)."""
    present = q[..., 0] != MISSING
    first = q[0].astype(np.int32)
    deltas = (q[1:].astype(np.int32) - q[:-1].astype(np.int32))[present[1:]]  # particles never reappear
    payload = np.concatenate([first.ravel(), deltas.ravel()])
    return np.packbits(present), lzma.compress(_shuffle(payload), preset=9)


def decode_positions(mask_bits: np.ndarray, blob: bytes, T: int, N: int) -> np.ndarray:
    present = np.unpackbits(mask_bits, count=T * N).astype(bool).reshape(T, N)
    payload = _unshuffle(lzma.decompress(blob), np.dtype(np.int32), 3 * N + 3 * int(present[1:].sum()))
    q = np.full((T, N, 3), MISSING, dtype=np.int32)
    q[0] = payload[: 3 * N].reshape(N, 3)
    deltas = payload[3 * N:].reshape(-1, 3)
    start = 0
    for t in range(1, T):
        idx = np.flatnonzero(present[t])
        q[t, idx] = q[t - 1, idx] + deltas[start:start + len(idx)]
        start += len(idx)
    return q.astype(np.int16)


def pack_file(path: Path, out: Path) -> None:
    with HopperFile(path) as f, h5py.File(path, "r") as raw:
        q = raw["snapshots/position"][()]
        mask, blob = encode_positions(q)
        np.savez(out, ids=f.ids, exit_time=f.exit_times.astype(np.float32), times=f.times, origin=f.origin,
                 resolution=f.resolution, mask=mask, positions=np.frombuffer(blob, dtype=np.uint8),
                 shape=np.array(q.shape[:2]), geometry=json.dumps(f.geometry.__dict__),
                 attrs=json.dumps({k: (v.item() if hasattr(v, "item") else v) for k, v in raw.attrs.items()}))


def unpack_file(packed: Path, out: Path) -> None:
    with np.load(packed) as z:
        T, N = (int(v) for v in z["shape"])
        q = decode_positions(z["mask"], z["positions"].tobytes(), T, N)
        origin, res = z["origin"], float(z["resolution"])
        pos = origin + res * q.astype(np.float64)
        pos[q[..., 0] == MISSING] = np.nan
        attrs = json.loads(str(z["attrs"]))
        traj = HopperTrajectory(ids=z["ids"], times=z["times"], positions=pos, velocities=None,
                                exit_times=z["exit_time"].astype(np.float64),
                                n_inserted=int(attrs.get("n_inserted", N)),
                                geometry=HopperGeometry(**json.loads(str(z["geometry"]))))
    write_hopper_file(out, attrs["sim_id"], traj, json.loads(attrs["params"]), attrs["solver_version"], res,
                      origin=origin)


def pack(dataset_dir: Path, out_dir: Path, max_part_mb: float = 60.0) -> list[Path]:
    m = Manifest.load(dataset_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    parts: list[Path] = []
    size = float("inf")
    for rec in m.usable():
        if size > max_part_mb * 2**20:
            parts.append(out_dir / f"part_{len(parts):03d}")
            parts[-1].mkdir(exist_ok=True)
            shutil.copy(dataset_dir / MANIFEST_NAME, parts[-1] / MANIFEST_NAME)
            size = 0.0
        target = parts[-1] / f"{rec.sim_id}.npz"
        pack_file(dataset_dir / str(rec.file), target)
        size += target.stat().st_size
    return parts


def unpack(parts: list[Path], dataset_dir: Path) -> Manifest:
    if not parts:
        raise DataError("nothing to unpack: give the part folders written by `pack`")
    m = Manifest.load(parts[0])
    with dataset_lock(dataset_dir, command_line("neuraldem.scenes.hopper.dataset.transfer")):
        (dataset_dir / "sims").mkdir(parents=True, exist_ok=True)
        done = set()
        for part in parts:
            for packed in sorted(Path(part).glob("*.npz")):
                rec = m.record(packed.stem)
                unpack_file(packed, dataset_dir / str(rec.file))
                rec.sha256 = sha256(dataset_dir / str(rec.file))
                rec.diagnostics["compact_copy"] = True
                done.add(rec.sim_id)
        for rec in m.usable():
            if rec.sim_id not in done:  # not shipped: not part of this copy
                rec.status, rec.reason = "failed", "not included in this compact copy"
        m.splits = {name: {part: [i for i in ids if i in done] for part, ids in split.items()}
                    for name, split in m.splits.items()}
        atomic_write_json(dataset_dir / MANIFEST_NAME, m.to_json())
    return m


@report_user_errors
def main(argv: list[str] | None = None) -> int:
    p = doc_parser("neuraldem.scenes.hopper.dataset.transfer", __doc__)
    sub = p.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("pack")
    a.add_argument("dataset", type=Path)
    a.add_argument("out", type=Path)
    a.add_argument("--max-part-mb", type=float, default=60.0)
    b = sub.add_parser("unpack")
    b.add_argument("parts", type=Path, nargs="+")
    b.add_argument("--dataset", type=Path, required=True)
    args = p.parse_args(argv)
    if args.cmd == "pack":
        parts = pack(args.dataset, args.out, args.max_part_mb)
        for part in parts:
            mb = sum(f.stat().st_size for f in part.iterdir()) / 2**20
            print(f"{part}: {len(list(part.glob('*.npz')))} simulations, {mb:.1f} MB")
    else:
        m = unpack(args.parts, args.dataset)
        print(f"unpacked {len(m.usable())} simulations into {args.dataset}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
