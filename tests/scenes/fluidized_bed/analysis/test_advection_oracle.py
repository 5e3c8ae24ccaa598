"""The advection oracle on the real fb_tiny trajectories: CFD-DEM's own flux carries the concentration, scored
with the evaluation's Lacey index; a model's rollouts (ckpt=) the same way; bad options in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from neuraldem.scenes.fluidized_bed.analysis.advection_oracle import advected_mixing
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from tests.helpers import run_module

pytestmark = pytest.mark.solver


def test_oracle_advection_stays_bounded_and_starts_from_the_data(fb_tiny_dataset: Path):
    with BedFile(fb_tiny_dataset / "sims" / "sim_0000.h5") as f:
        for c in (0.0, 1.0):
            mix = advected_mixing(f, "fct", c)
            assert mix.shape == f.mixing().shape
            np.testing.assert_array_equal(mix[0], f.mixing(0))
            assert mix.min() >= 0.0 and mix.max() <= 1.0

ORACLE = ("neuraldem", "report", "advection-oracle")


def test_cli_writes_the_table_for_the_oracle_and_a_model(fb_tiny_dataset: Path, fb_tiny_flux_checkpoint: Path,
                                                         tmp_path: Path):
    proc = run_module(*ORACLE, f"dataset={fb_tiny_dataset}", "sims=[sim_0000]", "corrections=[0,1]",
                      f"out={tmp_path / 'oracle'}")
    assert proc.returncode == 0, proc.stderr
    rows = json.loads((tmp_path / "oracle" / "oracle.json").read_text())["rows"]
    assert rows[0]["sim_id"] == "sim_0000" and {"mae_0", "mae_1"} <= set(rows[0])
    assert "| mean MAE, largest swing |" in (tmp_path / "oracle" / "oracle.md").read_text()
    # with fluxes made consistent with CFD-DEM's next solid fraction the tagged solid is kept from step to step
    proc = run_module(*ORACLE, f"dataset={fb_tiny_dataset}", "sims=[sim_0000]", "corrections=[0,1]",
                      "flux=consistent", f"out={tmp_path / 'consistent'}")
    assert proc.returncode == 0, proc.stderr
    (kept,) = json.loads((tmp_path / "consistent" / "oracle.json").read_text())["rows"]
    for c in ("0", "1"):
        assert kept[f"tagged_swing_pct_{c}"] < 0.5 * rows[0][f"tagged_swing_pct_{c}"], (kept, rows[0])
    proc = run_module(*ORACLE, f"dataset={fb_tiny_dataset}", "sims=[sim_0000]", f"ckpt={fb_tiny_flux_checkpoint}",
                      "steps=5", "corrections=[0.75]", "flux=consistent", f"out={tmp_path / 'model'}")
    assert proc.returncode == 0, proc.stderr
    (row,) = json.loads((tmp_path / "model" / "oracle.json").read_text())["rows"]
    assert len(row["lacey_0.75"]) == 6 and np.isfinite(row["mae_0.75"])


@pytest.mark.parametrize("options,message", [(["corrections=[1.5]"], "corrections=[1.5]: each must be in [0, 1]"),
                                             (["sims=[sim_0099]"], "sims=['sim_0099'] are not finished")])
def test_bad_options_end_in_one_line(fb_tiny_dataset: Path, options: list[str], message: str):
    proc = run_module(*ORACLE, f"dataset={fb_tiny_dataset}", *options)
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr
    assert proc.stderr.startswith("neuraldem: error: neuraldem report advection-oracle: ")
    assert proc.stderr.count("\n") == 1, proc.stderr
