"""One forward pass for several bed rollouts against one each (`bench fb_batch`): the benchmark on the tiny shipped
model writes both runtimes' times with each member answered as alone, and a batch or runtime out of range is one
line naming the option."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from neuraldem.bench.__main__ import main as bench_main

MODEL = "fb_tiny_test"


@pytest.fixture
def use_fb_tiny(fb_tiny_pretrained: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NEURALDEM_PRETRAINED_DIR", str(fb_tiny_pretrained))


def test_both_runtimes_timed_with_each_member_answered_as_alone(use_fb_tiny, tmp_path: Path):
    out = tmp_path / "fb_batch.json"
    assert bench_main(["fb_batch", f"model={MODEL}", "batch=3", "repeats=1", f"out={out}"]) == 0
    result = json.loads(out.read_text())["results"]
    assert result["batch"] == 3 and len(result["velocities"]) == 3
    assert set(result["runtimes"]) == {"torch", "onnx"}
    for r in result["runtimes"].values():
        assert r["largest_difference"] < 1e-3  # a member's outputs are its own call's, to round-off
        for key in ("call_one_each_ms_per_member", "call_for_all_ms_per_member", "step_one_each_ms_per_member",
                    "step_for_all_ms_per_member", "rollout_step_ms", "batched_rollout_step_bound_ms"):
            assert r[key] > 0, key
        assert r["batched_rollout_step_bound_ms"] == pytest.approx(
            r["rollout_step_ms"] * r["step_for_all_ms_per_member"] / r["step_one_each_ms_per_member"])
    table = out.with_suffix(".md").read_text()
    assert "| onnx |" in table and "batched, at best" in table


@pytest.mark.parametrize(("args", "message"), [
    (["batch=1"], "batch=1 is invalid: must be >= 2"),
    (["batch=65"], "batch=65 is invalid: must be <= 64"),
    (["runtime=gpu"], "runtime='gpu' is invalid: must be one of ['torch', 'onnx', 'both']"),
])
def test_a_batch_or_runtime_out_of_range_is_one_line(use_fb_tiny, tmp_path: Path, capsys: pytest.CaptureFixture,
                                                       args: list[str], message: str):
    with pytest.raises(SystemExit) as stop:
        bench_main(["fb_batch", f"model={MODEL}", *args, f"out={tmp_path / 'x.json'}"])
    assert stop.value.code == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and message in err[0], err
    assert not (tmp_path / "x.json").exists()
