"""Checkpoint selection on long validation rollouts (scenes.fluidized_bed.select).

The evaluator is replaced by one that writes a metrics.json with known pooled scores (synthetic numbers, said so):
what is tested here is the ranking, the averaging over rollout seeds, the copy of the winner, resuming and the
refusals; `neuraldem.evaluate` itself is tested in test_evaluation.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes.fluidized_bed.surrogate.selection import SELECTED, main, select


def make_run(tmp_path: Path, steps: list[int]) -> Path:
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    for s in steps:
        (run / "checkpoints" / f"step{s:06d}.ckpt").write_bytes(f"weights of step {s}".encode())
    (run / "checkpoints" / "last.ckpt").write_bytes(b"not a step checkpoint")
    return run


def fake_evaluator(scores: dict[tuple[int, int], float], calls: list, long_scores: dict | None = None):
    """Writes metrics.json whose pooled terms sum to scores[(step, seed)] over 4 velocities, or, for an evaluation on
    another dataset (`dataset_dir=`), to long_scores[(step, seed)] over 1 (synthetic, for the ranking only)."""

    def evaluate(ckpt: Path, out: Path, overrides: list[str]) -> Path:
        step = int(ckpt.name[4:10])
        seed = int(next(o for o in overrides if o.startswith("fluidized_bed.seed=")).split("=")[1])
        calls.append((step, seed, tuple(overrides)))
        long = any(o.startswith("dataset_dir=") for o in overrides)
        s = (long_scores if long else scores)[(step, seed)]
        n = 1 if long else 4
        out.mkdir(parents=True)
        agg = {"n_trajectories": n, "stable_at_10x": n, "pooled_solid_fraction_mean_rel_l2": s / 2,
               "pooled_solid_fraction_std_rel_l2": s / 4, "pooled_lacey_mae": s / 4}
        (out / "metrics.json").write_text(json.dumps({"aggregate": agg}))
        return out / "metrics.json"

    return evaluate


def test_the_lowest_mean_over_seeds_wins_and_is_copied(tmp_path: Path):
    run = make_run(tmp_path, [500, 1000, 1500, 2000])
    # step 1500 is best on seed 0 alone; step 2000 on the mean over both seeds
    scores = {(1000, 0): 0.30, (1000, 1): 0.30, (1500, 0): 0.20, (1500, 1): 0.40, (2000, 0): 0.25, (2000, 1): 0.26}
    calls: list = []
    doc = select(run, from_step=1000, rollout_noise=3, advection_correction=1, seeds=(0, 1),
                 evaluator=fake_evaluator(scores, calls))
    assert [r["step"] for r in doc["rows"]] == [1000, 1500, 2000]  # step 500 skipped
    assert doc["selected"]["step"] == 2000
    assert doc["rows"][1]["sum"] == pytest.approx(0.30) and doc["rows"][1]["sum_per_seed"] == pytest.approx([0.2, 0.4])
    assert (run / "checkpoints" / SELECTED).read_bytes() == b"weights of step 2000"
    assert ("fluidized_bed.rollout_noise=3" in calls[0][2]) and ("fluidized_bed.advection_correction=1" in calls[0][2])
    assert not any("mirror_alternate" in o for o in calls[0][2])  # as trained unless asked
    md = (run / "selection" / "noise3_corr1" / "selection.md").read_text()
    assert "| 2000 **selected** |" in md and "rollout seeds [0, 1]" in md
    assert json.loads((run / "selection" / "noise3_corr1" / "selection.json").read_text())["selected"]["step"] == 2000


def test_mirror_alternation_is_passed_on(tmp_path: Path):
    run = make_run(tmp_path, [1000, 2000])
    calls: list = []
    doc = select(run, mirror_alternate=True, evaluator=fake_evaluator({(1000, 0): 0.3, (2000, 0): 0.2}, calls))
    assert all("fluidized_bed.mirror_alternate=true" in c[2] for c in calls) and len(calls) == 2
    assert "mirror-alternating steps on" in (run / "selection" / "alt" / "selection.md").read_text()
    assert doc["mirror_alternate"] is True


def test_every_validated_checkpoint_of_experiment_fb_is_found(tmp_path: Path):
    """experiment=fb writes every validated checkpoint to checkpoints/all/ beside the kept one in checkpoints/."""
    run = make_run(tmp_path, [1500])  # the kept one
    (run / "checkpoints" / "all").mkdir()
    for s in (500, 1000, 1500):
        (run / "checkpoints" / "all" / f"step{s:06d}.ckpt").write_bytes(f"weights of step {s}".encode())
    calls: list = []
    doc = select(run, evaluator=fake_evaluator({(500, 0): 0.4, (1000, 0): 0.1, (1500, 0): 0.3}, calls))
    assert sorted(c[0] for c in calls) == [500, 1000, 1500] and doc["selected"]["step"] == 1000
    assert (run / "checkpoints" / SELECTED).read_bytes() == b"weights of step 1000"


def test_a_finished_evaluation_is_not_repeated(tmp_path: Path):
    run = make_run(tmp_path, [1000, 2000])
    scores = {(1000, 0): 0.3, (2000, 0): 0.2}
    first: list = []
    select(run, evaluator=fake_evaluator(scores, first))
    assert len(first) == 2
    assert (run / "selection" / "as_trained" / "step001000_seed0" / "evaluation" / "metrics.json").is_file()
    (run / "checkpoints" / "step003000.ckpt").write_bytes(b"weights of step 3000")
    again: list = []
    doc = select(run, evaluator=fake_evaluator({**scores, (3000, 0): 0.5}, again))
    assert [c[0] for c in again] == [3000]  # only the new checkpoint is evaluated
    assert doc["selected"]["step"] == 2000
    other: list = []  # other rollout options never reuse these evaluations
    select(run, rollout_noise=1, evaluator=fake_evaluator({**scores, (3000, 0): 0.5}, other))
    assert [c[0] for c in other] == [1000, 2000, 3000] and (run / "selection" / "noise1").is_dir()


def test_a_diverged_rollout_never_wins(tmp_path: Path):
    run = make_run(tmp_path, [1000, 2000])
    calls: list = []
    evaluate = fake_evaluator({(1000, 0): 0.9, (2000, 0): 0.1}, calls)

    def diverging(ckpt: Path, out: Path, overrides: list[str]) -> Path:
        metrics = evaluate(ckpt, out, overrides)
        if "step002000" in ckpt.name:
            doc = json.loads(metrics.read_text())
            doc["aggregate"]["stable_at_10x"] = 3
            metrics.write_text(json.dumps(doc))
        return metrics

    assert select(run, evaluator=diverging)["selected"]["step"] == 1000


def test_refusals_name_the_fix(tmp_path: Path, capsys):
    run = make_run(tmp_path, [8000])
    with pytest.raises(DataError, match="save_top_k=-1"):
        select(run, evaluator=fake_evaluator({}, []))
    with pytest.raises(DataError, match="no checkpoints/ folder"):
        select(tmp_path / "nowhere", evaluator=fake_evaluator({}, []))
    with pytest.raises(ConfigError, match="--rollout-noise"):
        select(run, rollout_noise=-1)
    with pytest.raises(ConfigError, match="--advection-correction"):
        select(run, advection_correction=2)
    with pytest.raises(ConfigError, match="--seeds"):
        select(run, seeds=())
    with pytest.raises(SystemExit) as exit_:  # the CLI reports it in one line instead of a traceback
        main([str(run)])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "save_top_k=-1" in err[0]


def make_long_val(tmp_path: Path, part: str = "val", name: str = "fb_small_longval") -> Path:
    """A dataset folder whose manifest lists one finished long trajectory in `part` of the long split (no file is
    read: the evaluator is replaced)."""
    ds = tmp_path / name
    m = Manifest(name=name, kind="fluidized_bed", scene={}, solver={}, parameters={})
    m.simulations = [SimRecord(sim_id="sim_0000", index=0, params={"inlet_velocity": 1.96, "duration": 30.0},
                               status="ok", file="sims/sim_0000.h5")]
    m.splits = {"velocity": {"train": [], "val": [], "test": []},
                "long": {"train": [], "val": [], "test": [], part: ["sim_0000"]}}
    m.save(ds)
    return ds


def test_long_validation_counts_as_one_more_velocity(tmp_path: Path):
    """Step 2000 is best on the 3-s validation part, step 1000 once its 30-s trajectory (one velocity of five)
    is pooled in: (4 x 0.20 + 0.60) / 5 = 0.28 against (4 x 0.25 + 0.25) / 5 = 0.25."""
    run = make_run(tmp_path, [1000, 2000])
    ds = make_long_val(tmp_path)
    calls: list = []
    short, long = {(1000, 0): 0.25, (2000, 0): 0.20}, {(1000, 0): 0.25, (2000, 0): 0.60}
    doc = select(run, rollout_noise=3, evaluator=fake_evaluator(short, calls, long), long_val=[ds])
    assert doc["selected"]["step"] == 1000
    rows = {r["step"]: r for r in doc["rows"]}
    assert rows[2000]["sum"] == pytest.approx(0.28) and rows[1000]["sum"] == pytest.approx(0.25)
    assert rows[2000]["sum_by_source"] == pytest.approx({"val": 0.20, "fb_small_longval": 0.60})
    assert rows[2000]["n_velocities"] == 5
    long_calls = [c for c in calls if f"dataset_dir={ds.resolve()}" in c[2]]
    assert len(long_calls) == 2 and all("fluidized_bed.rollout_noise=3" in c[2] for c in long_calls)
    sel = run / "selection" / "noise3"
    assert (sel / "step002000_seed0" / "fb_small_longval" / "evaluation" / "metrics.json").is_file()
    md = (sel / "selection_fb_small_longval.md").read_text()
    assert "long validation trajectories of fb_small_longval" in md and "| 1000 **selected** |" in md
    assert "0.600 |" in md
    # the 3-s evaluations are shared with a selection without it (resumed, not repeated); its winner copied elsewhere
    again: list = []
    doc = select(run, rollout_noise=3, evaluator=fake_evaluator(short, again), copy_to=tmp_path / "v" / "sel.ckpt")
    assert doc["selected"]["step"] == 2000 and (tmp_path / "v" / "sel.ckpt").read_bytes() == b"weights of step 2000"
    assert (run / "checkpoints" / SELECTED).read_bytes() == b"weights of step 1000"  # the first choice stays
    assert again == [] and (sel / "selection.md").is_file()


def test_long_validation_refusals(tmp_path: Path):
    run = make_run(tmp_path, [1000, 2000])
    with pytest.raises(DataError, match="no dataset at"):
        select(run, long_val=[tmp_path / "nowhere"], evaluator=fake_evaluator({}, []))
    test_only = make_long_val(tmp_path, part="test", name="fb_small")
    with pytest.raises(ConfigError, match="long.part=val"):
        select(run, long_val=[test_only], evaluator=fake_evaluator({}, []))
    ds = make_long_val(tmp_path)
    with pytest.raises(ConfigError, match="give each once"):
        select(run, long_val=[ds, ds], evaluator=fake_evaluator({}, []))


def test_long_validation_set_by_name_under_the_data_dir(tmp_path: Path, monkeypatch):
    monkeypatch.setenv("NEURALDEM_DATA", str(tmp_path / "data"))
    make_long_val(tmp_path / "data" / "datasets")
    run = make_run(tmp_path, [1000, 2000])
    calls: list = []
    doc = select(run, evaluator=fake_evaluator({(1000, 0): 0.3, (2000, 0): 0.2}, calls, {(1000, 0): 0.2,
                                                                                         (2000, 0): 0.2}),
                 long_val=[Path("fb_small_longval")])
    assert doc["long_val"] == {"fb_small_longval": str(tmp_path / "data" / "datasets" / "fb_small_longval")}
