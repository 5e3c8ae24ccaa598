"""`neuraldem export` on the tiny real datasets: both formats round-trip (positions float32-exact, types, dt,
splits), statistics from the training part only, and the refusals in one line."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from neuraldem.data.manifest import Manifest
from neuraldem.export.__main__ import export_dataset, main
from neuraldem.export.formats import MATERIAL, read_export
from neuraldem.gns.datamodule import ParticleRun

pytestmark = pytest.mark.solver
CASES = [("hopper_tiny", "gns"), ("hopper_tiny", "lagrangebench"), ("fb_tiny", "gns"), ("fb_tiny", "lagrangebench")]


@pytest.fixture(scope="module")
def exports(hopper_tiny_dataset: Path, fb_tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory):
    """One export per (dataset, format): the hopper with exits=hold (its particles drain), the bed as is."""
    root = tmp_path_factory.mktemp("exports")
    out = {}
    for name, fmt in CASES:
        dataset = hopper_tiny_dataset if name == "hopper_tiny" else fb_tiny_dataset
        out[name, fmt] = root / f"{name}_{fmt}"
        export_dataset(fmt, dataset, out[name, fmt], exits="hold" if name == "hopper_tiny" else "refuse")
    return out


def stored(dataset: Path, m: Manifest, sim_id: str) -> tuple[np.ndarray, float]:
    with ParticleRun(dataset / str(m.record(sim_id).file), m.kind, m.scene) as run:
        return run.positions(), run.dt


@pytest.mark.parametrize(("name", "fmt"), CASES)
def test_exports_round_trip(name: str, fmt: str, exports, request):
    dataset = request.getfixturevalue(f"{name}_dataset")
    m = Manifest.load(dataset)
    back = read_export(exports[name, fmt])
    info, split = back.info, back.info["split"]
    assert back.format == fmt and back.kind == m.kind and split == ("random" if name == "hopper_tiny" else "velocity")
    origin = np.asarray(info["origin"])
    for part, trajs in back.parts.items():
        assert [t.sim_id for t in trajs] == m.split_ids(split, part)
        for t in trajs:
            x, dt = stored(dataset, m, t.sim_id)
            assert back.metadata["dt"] == dt
            if fmt == "lagrangebench":  # every trajectory of a part cut to the part's shortest
                assert t.n_snapshots == min(len(stored(dataset, m, s)[0]) for s in m.split_ids(split, part))
            else:
                assert t.n_snapshots == len(x)
            want = (x[: t.n_snapshots] - origin).astype(np.float32)  # NaN where a particle has left
            np.testing.assert_array_equal(t.physical(), want.astype(np.float64))
            assert (t.particle_type == MATERIAL).all() and t.conditioning == m.record(t.sim_id).conditioning()
            if name == "fb_tiny":  # the bed stores float32 with its box at 0: the very same numbers
                np.testing.assert_array_equal(t.positions, x[: t.n_snapshots].astype(np.float32))
    lo, hi = back.box
    assert (lo == 0).all() and all((t.positions <= hi + 1e-6).all() for p in back.parts.values() for t in p)


@pytest.mark.parametrize(("name", "fmt"), [("hopper_tiny", "gns"), ("fb_tiny", "lagrangebench")])
def test_statistics_come_from_the_training_part(name: str, fmt: str, exports, request):
    dataset = request.getfixturevalue(f"{name}_dataset")
    m = Manifest.load(dataset)
    back = read_export(exports[name, fmt])
    meta, origin = back.metadata, np.asarray(back.info["origin"])

    def direct(parts):  # from the dataset's own files, as exported (float32 relative to the origin, cut)
        v, a = [], []
        for t in (t for p in parts for t in back.parts[p]):
            x = (stored(dataset, m, t.sim_id)[0][: t.n_snapshots] - origin).astype(np.float32).astype(np.float64)
            v.append((x[1:] - x[:-1]).reshape(-1, 3))  # per snapshot step, the tools' units; NaN: gone
            a.append((x[2:] - 2 * x[1:-1] + x[:-2]).reshape(-1, 3))
        v, a = (np.concatenate(c) for c in (v, a))
        v, a = v[np.isfinite(v).all(1)], a[np.isfinite(a).all(1)]
        return v.mean(0), v.std(0), a.mean(0), a.std(0)

    train = direct(["train"])
    for key, value in zip(("vel_mean", "vel_std", "acc_mean", "acc_std"), train, strict=True):
        np.testing.assert_allclose(meta[key], value, rtol=1e-9, atol=1e-15)
    everything = direct(["train", "val", "test"])
    assert not np.allclose(meta["vel_std"], everything[1], rtol=1e-6)  # the held-out runs are not in it
    assert meta["default_connectivity_radius"] == pytest.approx(2.0 * back.info["particle_diameter"])


def test_the_public_readers_keys(exports):
    gns = json.loads((exports["fb_tiny", "gns"] / "metadata.json").read_text())
    assert gns["sequence_length"] == 20 and gns["dim"] == 3 and gns["nnode_in"] == 38  # + the inlet velocity
    with np.load(exports["fb_tiny", "gns"] / "test.npz", allow_pickle=True) as z:
        positions, types, material = next(iter(z.values()))
    assert positions.shape == (21, 300, 3) and types.shape == (300,) and material == pytest.approx(2.041831)
    lb = json.loads((exports["hopper_tiny", "lagrangebench"] / "metadata.json").read_text())
    for key in ("case", "dim", "dt", "bounds", "default_connectivity_radius", "num_particles_max",
                "periodic_boundary_conditions", "sequence_length_train", "sequence_length_test", "vel_mean",
                "vel_std", "acc_mean", "acc_std", "write_every"):
        assert key in lb, key
    assert lb["num_particles_max"] == 500 and lb["sequence_length_train"] == 20  # the shortest training run: 21
    with h5py.File(exports["hopper_tiny", "lagrangebench"] / "train.h5", "r") as f:
        assert list(f)[0] == "00000" and f["00000/position"].dtype == np.float32
    assert not (exports["fb_tiny", "lagrangebench"] / "valid.h5").exists()  # fb_tiny's split has no val runs


def written(folder: Path) -> list[Path]:
    """The files under `folder` (an `out=` folder is created when the command line is read: it stays empty)."""
    return [p for p in folder.rglob("*") if not p.is_dir()]


def error_of(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.startswith("neuraldem: error: ") and err.count("\n") == 1, err
    return err


@pytest.mark.parametrize("fmt", ["gns", "lagrangebench"])
def test_a_growing_particle_set_is_refused_naming_the_kind(fmt, hopper_refill_tiny_dataset, tmp_path, capsys):
    err = error_of([fmt, f"dataset={hopper_refill_tiny_dataset}", f"out={tmp_path / 'out'}"], capsys)
    tool = {"gns": "GNS", "lagrangebench": "LagrangeBench"}[fmt]
    assert f"kind 'hopper_refill', which the {tool} format cannot hold" in err and "grows" in err
    assert written(tmp_path) == []


def test_leaving_particles_need_a_rule(hopper_tiny_dataset, tmp_path, capsys):
    err = error_of(["gns", f"dataset={hopper_tiny_dataset}", f"out={tmp_path / 'out'}"], capsys)
    assert "run sim_0000" in err and "particles leave" in err and "choose exits=truncate" in err
    err = error_of(["gns", f"dataset={hopper_tiny_dataset}", f"out={tmp_path / 'out'}", "exits=truncate"], capsys)
    assert "snapshots before its first particle leaves" in err and "use exits=hold" in err
    assert written(tmp_path) == []  # nothing half-written


def test_bad_input_is_one_line(hopper_tiny_dataset, fb_tiny_dataset, tmp_path, capsys):
    err = error_of(["gns", f"dataset={tmp_path / 'no_such_dataset'}", f"out={tmp_path / 'out'}"], capsys)
    assert "no dataset at" in err and "no_such_dataset" in err and "neuraldem datagen data=no_such_dataset" in err
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    busy = [f"dataset={hopper_tiny_dataset}", f"out={tmp_path / 'busy'}", "exits=hold"]
    err = error_of(["gns", *busy], capsys)
    assert "exists and is not empty" in err and "force=true" in err
    err = error_of(["gns", *busy, "force=true"], capsys)
    assert "not an earlier export" in err and (tmp_path / "busy" / "notes.txt").exists()
    err = error_of(["gns", f"dataset={hopper_tiny_dataset}", f"out={tmp_path / 'o'}", "split=nope"], capsys)
    assert "split='nope'" in err and "band" in err
    err = error_of(["gns", f"dataset={fb_tiny_dataset}", f"out={tmp_path / 'o'}", "material_property=mu_s"], capsys)
    assert "material_property='mu_s'" in err and "inlet_velocity" in err
    err = error_of(["lagrangebench", f"dataset={fb_tiny_dataset}", f"out={tmp_path / 'o'}",
                    "material_property=inlet_velocity"], capsys)
    assert "has no place for one" in err and not list((tmp_path / "o").iterdir())


def test_force_replaces_an_earlier_export(fb_tiny_dataset, tmp_path, capsys):
    out = tmp_path / "fb"
    assert main(["lagrangebench", f"dataset={fb_tiny_dataset}", f"out={out}"]) == 0
    assert "train 2, valid 0, test 1" in capsys.readouterr().out
    assert main(["gns", f"dataset={fb_tiny_dataset}", f"out={out}", "force=true", "material_property=none"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["metadata.json", "test.npz", "train.npz"]
    assert read_export(out).format == "gns" and not list(tmp_path.glob(".*partial"))


def test_the_old_positional_spelling_still_exports_with_a_note(fb_tiny_dataset, tmp_path, capsys):
    assert main(["lagrangebench", str(fb_tiny_dataset), str(tmp_path / "lb"), "--force"]) == 0
    err = capsys.readouterr().err
    assert "old spelling" in err and f"lagrangebench dataset={fb_tiny_dataset} out={tmp_path / 'lb'} force=true" in err
