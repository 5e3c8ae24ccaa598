"""Checkpoint selection on long validation rollouts (scenes.fluidized_bed.select).

The evaluator is replaced by one that writes a metrics.json with known pooled scores (synthetic numbers, said so):
what is tested here is the ranking, the averaging over rollout seeds, the copy of the winner, resuming and the
refusals; `neuraldem.evaluate` itself is tested in test_evaluation.py, and there that the evaluation fb-select
calls is that of `neuraldem evaluate part=val`, file for file.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.data.manifest import Manifest, SimRecord
from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes.fluidized_bed.surrogate.options import RolloutOptions
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
    another dataset (`dataset_dir`), to long_scores[(step, seed)] over 1 (synthetic, for the ranking only); records
    (step, seed, the options as overrides, the dataset folder)."""

    def evaluate(ckpt: Path, out: Path, seed: int, dataset_dir: Path | None, options: RolloutOptions) -> Path:
        step = int(ckpt.name[4:10])
        calls.append((step, seed, tuple(options.overrides()), dataset_dir))
        long = dataset_dir is not None
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
    options = RolloutOptions(rollout_noise=3, advection_correction=1)
    doc = select(run, from_step=1000, options=options, seeds=(0, 1), evaluator=fake_evaluator(scores, calls))
    assert [r["step"] for r in doc["rows"]] == [1000, 1500, 2000]  # step 500 skipped
    assert doc["selected"]["step"] == 2000
    assert doc["rows"][1]["sum"] == pytest.approx(0.30) and doc["rows"][1]["sum_per_seed"] == pytest.approx([0.2, 0.4])
    assert (run / "checkpoints" / SELECTED).read_bytes() == b"weights of step 2000"
    assert calls[0][2] == ("rollout.advection_correction=1", "rollout.rollout_noise=3")  # the others as trained
    sel = run / "selection" / "advection_correction-1+rollout_noise-3"  # the folder of these options
    md = (sel / "selection.md").read_text()
    assert "| 2000 **selected** |" in md and "rollout seeds [0, 1]" in md
    assert "rollout options rollout.advection_correction=1 rollout.rollout_noise=3 (the others as trained)" in md
    doc = json.loads((sel / "selection.json").read_text())
    assert doc["selected"]["step"] == 2000 and doc["rollout_noise"] == 3 and doc["mirror_alternate"] is None


def test_mirror_alternation_is_passed_on(tmp_path: Path):
    run = make_run(tmp_path, [1000, 2000])
    calls: list = []
    doc = select(run, options=RolloutOptions(mirror_alternate=True),
                 evaluator=fake_evaluator({(1000, 0): 0.3, (2000, 0): 0.2}, calls))
    assert all(c[2] == ("rollout.mirror_alternate=true",) for c in calls) and len(calls) == 2
    md = (run / "selection" / "mirror_alternate-true" / "selection.md").read_text()
    assert "rollout options rollout.mirror_alternate=true" in md
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
    select(run, options=RolloutOptions(rollout_noise=1), evaluator=fake_evaluator({**scores, (3000, 0): 0.5}, other))
    assert [c[0] for c in other] == [1000, 2000, 3000] and (run / "selection" / "rollout_noise-1").is_dir()


def test_a_diverged_rollout_never_wins(tmp_path: Path):
    run = make_run(tmp_path, [1000, 2000])
    calls: list = []
    evaluate = fake_evaluator({(1000, 0): 0.9, (2000, 0): 0.1}, calls)

    def diverging(ckpt: Path, out: Path, *args) -> Path:
        metrics = evaluate(ckpt, out, *args)
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
    with pytest.raises(SystemExit) as exit_:  # a bad option: one line naming the key, before anything runs
        main([f"run_dir={run}", "rollout.rollout_noise=-1"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "rollout.rollout_noise=-1 is invalid: must be a number in [0, 10]" in err[0], err
    with pytest.raises(ConfigError, match="seeds="):
        select(run, seeds=())
    with pytest.raises(SystemExit) as exit_:  # the CLI reports it in one line instead of a traceback
        main([f"run_dir={run}"])
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
    doc = select(run, options=RolloutOptions(rollout_noise=3), evaluator=fake_evaluator(short, calls, long),
                 long_val=[ds])
    assert doc["selected"]["step"] == 1000
    rows = {r["step"]: r for r in doc["rows"]}
    assert rows[2000]["sum"] == pytest.approx(0.28) and rows[1000]["sum"] == pytest.approx(0.25)
    assert rows[2000]["sum_by_source"] == pytest.approx({"val": 0.20, "fb_small_longval": 0.60})
    assert rows[2000]["n_velocities"] == 5
    long_calls = [c for c in calls if c[3] == ds.resolve()]
    assert len(long_calls) == 2 and all(c[2] == ("rollout.rollout_noise=3",) for c in long_calls)
    sel = run / "selection" / "rollout_noise-3"
    assert (sel / "step002000_seed0" / "fb_small_longval" / "evaluation" / "metrics.json").is_file()
    md = (sel / "selection_fb_small_longval.md").read_text()
    assert "long validation trajectories of fb_small_longval" in md and "| 1000 **selected** |" in md
    assert "0.600 |" in md
    # the 3-s evaluations are shared with a selection without it (resumed, not repeated); its winner copied elsewhere
    again: list = []
    doc = select(run, options=RolloutOptions(rollout_noise=3), evaluator=fake_evaluator(short, again),
                 copy_to=tmp_path / "v" / "sel.ckpt")
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


def test_its_evaluation_is_that_of_the_evaluate_command(tmp_path: Path, monkeypatch):
    """fb-select calls the evaluation function with what `neuraldem evaluate ckpt=C part=val vtk=false
    fluidized_bed.seed=S [dataset_dir=D] rollout.* hydra.run.dir=OUT` passes it (defaults included): the same
    rollouts, metrics.json and report.md as the command it used to run."""
    import inspect

    from neuraldem.scenes.fluidized_bed import evaluate as evaluate_command
    from neuraldem.scenes.fluidized_bed.analysis import evaluation
    from neuraldem.scenes.fluidized_bed.surrogate import selection
    from neuraldem.scenes.fluidized_bed.surrogate.rollout import DivergenceLimits
    from tests.helpers import compose_cfg

    class Called(Exception):
        pass

    calls, signature = [], inspect.signature(evaluation.evaluate_checkpoint)

    def capture(*args, **kwargs):
        bound = signature.bind(*args, **kwargs)
        bound.apply_defaults()
        a = dict(bound.arguments)
        a["horizons"], a["limits"] = list(a["horizons"]), a["limits"] or DivergenceLimits()
        calls.append(a)
        raise Called

    monkeypatch.setattr(evaluation, "evaluate_checkpoint", capture)
    monkeypatch.setattr(selection, "evaluate_checkpoint", capture)
    ckpt, out, longval = tmp_path / "step001000.ckpt", tmp_path / "out", tmp_path / "longval"
    options = RolloutOptions(rollout_noise=3, advection_correction=1, mirror_alternate=True)
    for dataset_dir in (None, longval):
        extra = [] if dataset_dir is None else [f"dataset_dir={dataset_dir}"]
        cfg = compose_cfg("evaluate", [f"ckpt={ckpt}", "part=val", "vtk=false", "fluidized_bed.seed=1", *extra,
                                       "rollout.rollout_noise=3", "rollout.advection_correction=1",
                                       "rollout.mirror_alternate=true"], out)
        with pytest.raises(Called):
            evaluate_command(cfg)
        with pytest.raises(Called):
            selection.run_evaluate(ckpt, out, 1, dataset_dir, options)
        command, function = calls[-2:]
        command["dataset_dir"] = None if command["dataset_dir"] is None else Path(command["dataset_dir"])
        assert function == command and function["options"] == options and function["part"] == "val"
