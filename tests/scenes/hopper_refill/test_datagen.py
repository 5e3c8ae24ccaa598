"""The refilling hopper generated with real LIGGGHTS runs (hopper_refill_tiny): the fill level stays in its
band, particle ids and insertion times are consistent, and the stored files validate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neuraldem.data.manifest import Manifest
from neuraldem.scenes.hopper_refill.store import RefillFile

pytestmark = pytest.mark.solver


def _files(dataset: Path) -> list[tuple[object, RefillFile]]:
    m = Manifest.load(dataset)
    assert m.kind == "hopper_refill"
    return [(rec, RefillFile(dataset / str(rec.file))) for rec in m.usable()]


def test_fill_level_stays_in_its_band(hopper_refill_tiny_dataset: Path):
    m = Manifest.load(hopper_refill_tiny_dataset)
    lo, hi = m.scene["refill"]["level_band"]
    interval = m.scene["refill"]["interval"]
    for rec, f in _files(hopper_refill_tiny_dataset):
        with f:
            levels = np.array([(f.frame(k)[1][:, 2] >= 0).sum() for k in range(f.n_snapshots)]) / f.n_initial
            steady = levels[f.times >= interval]  # after the first top-up
            assert f.times[-1] == pytest.approx(m.scene["hopper"]["max_time"]), rec.sim_id  # ran to the end
            assert lo <= steady.min() and steady.max() <= hi, (rec.sim_id, steady.min(), steady.max())
            # material really was refilled: more particles passed through than the hopper holds
            assert np.isfinite(f.exit_times).sum() > 1.5 * f.n_initial, rec.sim_id
            assert rec.metrics["level_min"] == pytest.approx(steady.min())


def test_ids_and_insertion_times_are_consistent(hopper_refill_tiny_dataset: Path):
    m = Manifest.load(hopper_refill_tiny_dataset)
    n0 = m.scene["hopper"]["n_particles"]
    interval, dt = m.scene["refill"]["interval"], m.scene["hopper"]["material"]["dt"]
    settle = m.scene["hopper"]["settle_time"]
    for rec, f in _files(hopper_refill_tiny_dataset):
        with f:
            tr = f.load()
        fill = tr.insert_times < 0
        # the fill: ids 1..N0, inserted on the first step of the run (settle_time before the opening)
        assert fill.sum() == n0 and tr.ids[fill].tolist() == list(range(1, n0 + 1))
        np.testing.assert_allclose(tr.insert_times[fill], dt - settle, atol=1e-9)
        # refilled material: new ids (beyond the fill and the sentinel N0 + 1), numbered in insertion order,
        # inserted on the first step of a top-up interval
        new = ~fill
        assert new.sum() == rec.diagnostics["n_refilled"] > 0
        assert tr.ids[new].min() > n0 + 1
        assert np.all(np.diff(tr.insert_times[new]) >= 0)
        steps = (tr.insert_times[new] - dt) / interval
        np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
        # first seen in the first snapshot after its insertion; exits after it
        counts = np.diff(tr.offsets)
        snap = np.repeat(np.arange(len(tr.times)), counts)
        first = np.full(tr.n_particles, len(tr.times))
        np.minimum.at(first, tr.index, snap)
        seen = tr.times[first[new]]
        assert np.all(seen >= tr.insert_times[new] - 1e-9)
        assert np.all(seen < tr.insert_times[new] + f.times[1] + 1e-9)
        left = np.isfinite(tr.exit_times)
        assert np.all(tr.exit_times[left] > tr.insert_times[left])
        # every particle is in the hopper at the end or has exited (none lost), each id exactly once
        present_end = tr.frame(len(tr.times) - 1)[0]
        assert len(present_end) + left.sum() == tr.n_particles - int(np.isin(np.flatnonzero(left), present_end).sum())
        assert rec.diagnostics["n_lost"] == 0


@pytest.mark.parametrize(("override", "message"), [
    ("data.refill.interval=0.00015", "data.refill.interval=0.00015 is invalid: must be a multiple of"),
    ("data.refill.level_band=[1.1,1.2]", "data.refill.level_band=[1.1, 1.2] is invalid: needs 0 < lo < 1 <= hi"),
    ("+data.refill.rate=3", "unknown key(s) ['rate'] in data.refill"),
])
def test_bad_refill_values_end_in_one_line(tmp_path: Path, override: str, message: str):
    from tests.helpers import run_module

    proc = run_module("neuraldem", "datagen", "data=hopper_refill_tiny", "n_sims=1", "progress=false", override,
                      env={"NEURALDEM_DATA": str(tmp_path)})
    assert proc.returncode == 2, proc.stderr
    assert message in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "datasets" / "hopper_refill_tiny" / "sims").exists()  # refused before any run
