"""A real DPMFoam run read back: fluid continuity in every step, every particle and the solver's alpha volume
kept."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neuraldem.scenes.fluidized_bed.solver.reader import read_flux_monitor, read_trajectory
from neuraldem.sim.foam_reader import FoamCase


@pytest.mark.solver
def test_fluid_inflow_equals_outflow_every_step(fb_tiny_case: Path):
    """Continuity of the air: volume flow in through the bottom = out through the top in every solver step
    (pressure solver tolerance 1e-7), and equal to the superficial inlet velocity times the inlet area."""
    import json

    u0 = json.loads((fb_tiny_case / "neuraldem_case.json").read_text())["inlet_velocity"]
    t_in, f_in = read_flux_monitor(fb_tiny_case, "flux_bottom")
    t_out, f_out = read_flux_monitor(fb_tiny_case, "flux_top")
    assert len(t_in) == len(t_out) == 2500 and np.array_equal(t_in, t_out)
    steps = t_in > 0.0001 + 1e-9  # the first step starts the flow from rest
    inflow, outflow = -f_in[steps], f_out[steps]
    area = 0.024 * 0.006
    np.testing.assert_allclose(inflow, u0 * area, rtol=1e-6)
    imbalance = np.abs(inflow - outflow) / inflow
    assert imbalance.max() < 1e-5, imbalance.max()


@pytest.mark.solver
def test_run_keeps_every_particle_and_the_solver_alpha_volume(fb_tiny_case: Path, tiny_scene):
    case = FoamCase(fb_tiny_case)
    traj = read_trajectory(case, tiny_scene.grid, tiny_scene.spinup_time, tiny_scene.snapshot_interval)
    assert traj.positions.shape == (21, 300, 3) and traj.times[-1] == pytest.approx(0.2)
    assert np.isfinite(traj.positions).all() and not np.isfinite(traj.lost_time).any()
    solid = (1 - traj.fluid_fraction).sum(axis=(1, 2, 3)) * tiny_scene.grid.cell_volume
    np.testing.assert_allclose(solid, 300 * tiny_scene.particle_volume, rtol=1e-6)
    # the bed is fluidized: particles move between snapshots, air rises
    assert np.median(np.linalg.norm(np.diff(traj.positions, axis=0), axis=2)) > 1e-4
    assert traj.fluid_velocity[..., 2].mean() > 1.0
