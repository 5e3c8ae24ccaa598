"""The analysis notebooks run top to bottom on real (tiny) checkpoints."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import pytest

from neuraldem.scenes.fluidized_bed.surrogate.option_aliases import RESULT_CONSERVE_KEY
from tests.helpers import run_notebook

pytestmark = pytest.mark.solver


def test_hopper_evaluation_notebook_runs(tiny_checkpoint: Path, data_root: Path, tmp_path: Path, monkeypatch):
    matplotlib.use("Agg")
    monkeypatch.setenv("NEURALDEM_CKPT", str(tiny_checkpoint))
    monkeypatch.setenv("NEURALDEM_NOTEBOOK_OUT", str(tmp_path))
    monkeypatch.setenv("NEURALDEM_NOTEBOOK_MAX_SIMS", "1")
    namespace = run_notebook("hopper_evaluation.ipynb")
    assert namespace["result"]["aggregate"]["n_sims"] == 1
    assert (tmp_path / "metrics.json").is_file()
    assert set(namespace["rows"]) == {"field model", "constant", "gp"}  # the baselines on the same run


def test_fb_evaluation_notebook_runs(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path, tmp_path: Path, monkeypatch):
    matplotlib.use("Agg")
    monkeypatch.setenv("NEURALDEM_DATA", str(fb_tiny_dataset.parent.parent))
    monkeypatch.setenv("NEURALDEM_CKPT", str(fb_tiny_checkpoint))
    monkeypatch.setenv("NEURALDEM_NOTEBOOK_OUT", str(tmp_path))
    monkeypatch.setenv("NEURALDEM_NOTEBOOK_HORIZONS", "1,2")
    namespace = run_notebook("fb_evaluation.ipynb")
    model, projected = namespace["result"], namespace["projected"]
    assert model["aggregate"]["n_trajectories"] == projected["aggregate"]["n_trajectories"] == 1
    assert not model[RESULT_CONSERVE_KEY] and projected[RESULT_CONSERVE_KEY]  # rollout.conserve_volume=true
    assert abs(projected["trajectories"][0]["mass"]["max_drift_pct"]) < 1e-3  # float32 files
    assert (tmp_path / "model" / "metrics.json").is_file() and (tmp_path / "projected" / "report.md").is_file()


def test_refill_evaluation_notebook_runs(refill_tiny_checkpoint: Path, hopper_refill_tiny_dataset: Path,
                                         tmp_path: Path, monkeypatch):
    matplotlib.use("Agg")
    monkeypatch.setenv("NEURALDEM_DATA", str(hopper_refill_tiny_dataset.parent.parent))
    monkeypatch.setenv("NEURALDEM_CKPT", str(refill_tiny_checkpoint))
    monkeypatch.setenv("NEURALDEM_NOTEBOOK_OUT", str(tmp_path))
    monkeypatch.setenv("NEURALDEM_NOTEBOOK_HORIZON", "0.1")
    result = run_notebook("refill_evaluation.ipynb")["result"]
    assert result["horizon"] == 0.1 and result["aggregate"]["n_sims"] == result["persistence"]["n_sims"] == 1
    assert (tmp_path / "metrics.json").is_file() and (tmp_path / "refill_transport.png").is_file()
