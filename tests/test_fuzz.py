"""Bad inputs end in one line that names the file or key and the fix, and change nothing else.

Each case damages a copy of a real tiny dataset (or writes a bad solver file, or sets a bad config value),
runs what a user runs on it (a dataset reader, the manifest, the dump reader, config composition), and
checks the error: one line, the file or key in it, a fix, and every other file of the dataset as it was.
HDF5 cases re-record the file's checksum in the manifest (as if another tool wrote the file), so that the
reader itself is tested, not only the checksum.

`python -m tests.test_fuzz dataset=DIR table=docs/fuzz-table.md` writes the table of cases and messages (docs).
"""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import pytest

from neuraldem.data.manifest import Manifest
from neuraldem.errors import NeuraldemError
from tests.helpers import flip_byte, rerecord_checksum


@dataclass(frozen=True)
class Case:
    name: str  # the input, as the table shows it
    damage: Callable[[Path, Path], None]  # (dataset copy, the file of its first run) -> None
    run: Callable[[Path, Path], object]  # what a user runs on it
    names: str  # the file, field or key the message must name ("{file}" = the damaged run's file)
    says: str  # a phrase of the problem


def _h5(edit: Callable[[h5py.File], None]) -> Callable[[Path, Path], None]:
    def damage(ds: Path, path: Path) -> None:
        with h5py.File(path, "r+") as f:
            edit(f)
        rerecord_checksum(ds, path)
    return damage


def _replace(name: str, make: Callable[[np.ndarray], np.ndarray]) -> Callable[[h5py.File], None]:
    def edit(f: h5py.File) -> None:
        old = f[name]
        data, attrs = make(old[()]), dict(old.attrs)
        del f[name]
        f.create_dataset(name, data=data)
        f[name].attrs.update(attrs)
    return edit


def _truncate(ds: Path, path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    rerecord_checksum(ds, path)


def _flip_byte(ds: Path, path: Path) -> None:
    flip_byte(path)


def _open_run(ds: Path, path: Path) -> object:
    from neuraldem.scenes.hopper.dataset.store import HopperFile

    with HopperFile(path) as f:
        return f.n_particles


def _write(name: str, text: str) -> Callable[[Path, Path], None]:
    def damage(ds: Path, path: Path) -> None:
        (ds / name).write_text(text)
    return damage


def _edit_manifest(edit: Callable[[dict], None]) -> Callable[[Path, Path], None]:
    def damage(ds: Path, path: Path) -> None:
        m = json.loads((ds / "manifest.json").read_text())
        edit(m)
        (ds / "manifest.json").write_text(json.dumps(m))
    return damage


def _dump(body: str) -> Callable[[Path, Path], None]:
    header = "ITEM: TIMESTEP\n0\nITEM: NUMBER OF ATOMS\n2\nITEM: BOX BOUNDS pp pp pp\n0 1\n0 1\n0 1\n"
    return _write("user_dump.txt", header + "ITEM: ATOMS id x y z vx vy vz\n" + body)


def _read_dump(ds: Path, path: Path) -> object:
    from neuraldem.sim.dump import read_dump

    return read_dump(ds / "user_dump.txt")


def _read_exits(ds: Path, path: Path) -> object:
    from neuraldem.sim.dump import read_exit_file

    return read_exit_file(ds / "user_exits.txt")


def _train_cfg(*overrides: str) -> Callable[[Path, Path], object]:
    def run(ds: Path, path: Path) -> object:
        from neuraldem.train import train
        from tests.helpers import compose_cfg

        cfg = compose_cfg("train", ["experiment=hopper_quickstart", "logger=none", f"data.dataset_dir={ds}",
                                    *overrides], ds.parent / "run")
        return train(cfg)
    return run


def _datagen_cfg(*overrides: str) -> Callable[[Path, Path], object]:
    def run(ds: Path, path: Path) -> object:
        from omegaconf import open_dict

        from neuraldem.scenes import scene
        from tests.helpers import compose_cfg

        cfg = compose_cfg("datagen", ["data=hopper_tiny", *overrides], ds.parent / "run")
        with open_dict(cfg):
            cfg.data.dataset_dir = str(ds)
        return scene(cfg.data.kind).pipeline(cfg.data)
    return run


def _nothing(ds: Path, path: Path) -> None:
    return None


CASES = [
    Case("HDF5 run file cut to half its size", _truncate, _open_run, "{file}", "not a readable HDF5 file"),
    Case("HDF5 run file with one byte changed (checksum as written)", _flip_byte, _open_run, "{file}",
         "contents differ from the SHA-256"),
    Case("HDF5 without /snapshots/time", _h5(lambda f: f.__delitem__("snapshots/time")), _open_run, "/snapshots/time",
         "is missing"),
    Case("HDF5 with NaN in /snapshots/velocity",
         _h5(_replace("snapshots/velocity", lambda v: np.where(np.arange(v.size).reshape(v.shape) == 7, np.nan, v))),
         _open_run, "/snapshots/velocity", "NaN/inf"),
    Case("HDF5 with inf in /particles/exit_time",
         _h5(_replace("particles/exit_time", lambda e: np.full_like(e, np.inf))), _open_run,
         "/particles/exit_time", "infinite"),
    Case("HDF5 of schema version 99", _h5(lambda f: f.attrs.__setitem__("schema_version", 99)), _open_run, "{file}",
         "schema version 99"),
    Case("HDF5 with /snapshots/position as float32",
         _h5(_replace("snapshots/position", lambda q: q.astype(np.float32))), _open_run,
         "/snapshots/position", "dtype float32"),
    Case("HDF5 of another kind (fluidized_bed)", _h5(lambda f: f.attrs.__setitem__("kind", "fluidized_bed")),
         _open_run, "{file}", "kind 'fluidized_bed'"),
    Case("manifest.json empty", _write("manifest.json", ""), lambda ds, p: Manifest.load(ds), "manifest.json",
         "not valid JSON"),
    Case("manifest.json `{}`", _write("manifest.json", "{}"), lambda ds, p: Manifest.load(ds), "manifest.json",
         "schema version None"),
    Case("manifest.json with a run of status 'done'",
         _edit_manifest(lambda m: m["simulations"][0].__setitem__("status", "done")), lambda ds, p: Manifest.load(ds),
         "manifest.json", "unknown status 'done'"),
    Case("LIGGGHTS dump cut mid-frame", _dump("1 0.1 0.1 0.1 0 0 0\n2 0.2 0.2\n"), _read_dump, "user_dump.txt",
         "truncated"),
    Case("LIGGGHTS dump with a garbled number", _dump("1 0.1 0.1 0.1 0 0 0\n2 0.2 0.2 0,2 0 0 0\n"), _read_dump,
         "user_dump.txt", "non-numeric"),
    Case("LIGGGHTS dump with NaN", _dump("1 0.1 0.1 0.1 0 0 0\n2 0.2 0.2 nan 0 0 0\n"), _read_dump, "user_dump.txt",
         "NaN or inf"),
    Case("exit file with a garbled line", _write("user_exits.txt", "1 0.5\nabc\n"), _read_exits, "user_exits.txt",
         "expected 'id time"),
    Case("config: data.datamodule.batch_size=0", _nothing, _train_cfg("data.datamodule.batch_size=0"),
         "data.datamodule.batch_size", "must be a positive integer"),
    Case("config: model.net.num_heads=5", _nothing, _train_cfg("model.net.num_heads=5"), "model.net.num_heads",
         "must divide model.net.dim"),
    Case("config: trainer.max_steps=-5", _nothing, _train_cfg("trainer.max_steps=-5"), "trainer.max_steps",
         "is invalid"),
    Case("parameter range reversed: alpha [60, 0]", _nothing, _datagen_cfg("data.parameters.ranges.alpha=[60,0]"),
         "data.parameters.ranges.alpha", "lo <= hi"),
    Case("parameter outside the paper's range: mu_s [-1, 1]", _nothing,
         _datagen_cfg("data.parameters.ranges.mu_s=[-1,1]"), "data.parameters.ranges.mu_s", "must be >="),
]


def snapshot(ds: Path) -> dict[str, str]:
    return {p.relative_to(ds).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(ds.rglob("*")) if p.is_file()}


def run_case(case: Case, dataset: Path, work: Path) -> NeuraldemError:
    """The error `case` ends in, checked (one line, names, fix, nothing changed); AssertionError otherwise."""
    ds = work / "ds"
    shutil.copytree(dataset, ds)
    path = ds / str(Manifest.load(ds).usable()[0].file)
    case.damage(ds, path)
    before = snapshot(ds)
    try:
        case.run(ds, path)
    except NeuraldemError as err:
        msg, names = str(err), case.names.replace("{file}", str(path))
        assert "\n" not in msg, f"{case.name}: more than one line: {msg!r}"
        assert names in msg, f"{case.name}: {names!r} not named in {msg!r}"
        assert case.says in msg, f"{case.name}: {case.says!r} not said in {msg!r}"
        assert err.fix or "(override it, e.g." in msg, f"{case.name}: no fix in {msg!r}"  # config: the override
        assert snapshot(ds) == before, f"{case.name}: the dataset changed"
        return err
    raise AssertionError(f"{case.name}: accepted")


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_input_ends_in_one_line_with_file_and_fix(case: Case, hopper_tiny_dataset: Path, tmp_path: Path):
    run_case(case, hopper_tiny_dataset, tmp_path)


def test_an_extra_hdf5_field_is_ignored(hopper_tiny_dataset: Path, tmp_path: Path):
    """Fields a reader does not know (another tool's additions) are not an error."""
    ds = tmp_path / "ds"
    shutil.copytree(hopper_tiny_dataset, ds)
    path = ds / str(Manifest.load(ds).usable()[0].file)
    _h5(lambda f: f.create_dataset("extra/notes", data=np.arange(3)))(ds, path)
    assert _open_run(ds, path) > 0


def write_table(dataset: Path, out: Path, work: Path) -> None:
    rows = ["| input | message |", "|---|---|"]
    for i, case in enumerate(CASES):
        err = run_case(case, dataset, work / str(i))
        msg = str(err).replace(str(work), "<tmp>").replace("|", "\\|")
        rows.append(f"| {case.name} | `` {msg} `` |")
    out.write_text("# Bad inputs and what they say\n\nEvery row is a case of `tests/test_fuzz.py` (run in the default "
                   "test suite), on a copy of the tiny hopper dataset; written by `python -m tests.test_fuzz "
                   "dataset=DIR table=docs/fuzz-table.md`. Each message is one line with the file or key and a "
                   "fix, and the rest of the dataset is unchanged.\n\n" + "\n".join(rows) + "\n")


if __name__ == "__main__":
    import tempfile

    from neuraldem.cli import CommandParser

    p = CommandParser(prog="python -m tests.test_fuzz", description="write the table of bad inputs and their messages")
    p.add_argument("--dataset", type=Path, required=True, help="a hopper_tiny dataset (the tests make one)")
    p.add_argument("--table", type=Path, required=True)
    a = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        write_table(a.dataset, a.table, Path(tmp))
    print(f"wrote {a.table}")
    sys.exit(0)
