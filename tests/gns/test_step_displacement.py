"""Per-snapshot particle displacements: known values by hand, and the real tiny datasets of both scenes."""

from __future__ import annotations

import numpy as np
import pytest

from neuraldem.gns.step_displacement import displacements, main, step_statistics


def test_displacements_in_diameters_skip_absent_particles():
    pos = np.zeros((3, 2, 3))
    pos[1, 0] = [0.03, 0.04, 0.0]  # 0.05 m = 5 diameters of 0.01 m, then back
    pos[2, 1] = np.nan  # particle 1 has left: its last step is not a displacement
    d = displacements(pos, np.array([0.01, 0.02]))
    np.testing.assert_allclose(sorted(d), [0.0, 5.0, 5.0])


@pytest.mark.solver
@pytest.mark.parametrize("name", ["hopper_tiny", "fb_tiny"])
def test_statistics_of_a_real_dataset(name, request, tmp_path):
    dataset = request.getfixturevalue(f"{name}_dataset")
    s = step_statistics(dataset, n_runs=2)
    assert s["n_displacements"] > 0 and len(s["runs"]) == 2
    assert 0.0 <= s["median"] <= s["p90"] <= s["p99"] <= s["max"] < 50.0
    out = tmp_path / "steps.json"
    assert main([f"dataset={dataset}", "runs=1", f"out={out}"]) == 0 and out.is_file()


def test_bad_run_count_is_refused(hopper_tiny_dataset, capsys):
    with pytest.raises(SystemExit) as exc:
        main([f"dataset={hopper_tiny_dataset}", "runs=0"])
    assert exc.value.code == 2 and "config value runs=0 is invalid" in capsys.readouterr().err
