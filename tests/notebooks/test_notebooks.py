"""The analysis notebook runs top to bottom on a real (tiny) checkpoint."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib
import pytest

from tests.helpers import REPO

pytestmark = pytest.mark.solver


def test_hopper_evaluation_notebook_runs(tiny_checkpoint: Path, data_root: Path, tmp_path: Path, monkeypatch):
    matplotlib.use("Agg")
    monkeypatch.setenv("NEURALDEM_CKPT", str(tiny_checkpoint))
    monkeypatch.setenv("NEURALDEM_NOTEBOOK_OUT", str(tmp_path))
    monkeypatch.setenv("NEURALDEM_NOTEBOOK_MAX_SIMS", "1")
    nb = json.loads((REPO / "notebooks" / "hopper_evaluation.ipynb").read_text())
    namespace: dict = {}
    for cell in nb["cells"]:
        if cell["cell_type"] == "code":
            exec(compile("".join(cell["source"]), "hopper_evaluation.ipynb", "exec"), namespace)
    assert namespace["result"]["aggregate"]["n_sims"] == 1
    assert (tmp_path / "metrics.json").is_file()
