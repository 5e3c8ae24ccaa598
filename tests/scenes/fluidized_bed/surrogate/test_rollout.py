"""Rollouts of a tiny fluidized-bed model: files written and readable, divergence caught at the right step,
ground truth never flagged, and bad input (other kind or scene, other grid, extrapolation) handled."""

from __future__ import annotations

import json
import logging
import re
import warnings
from pathlib import Path

import meshio
import numpy as np
import pytest
import torch

from neuraldem.errors import ConfigError, DataError
from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
from neuraldem.scenes.fluidized_bed.surrogate.normalization import grid_input
from neuraldem.scenes.fluidized_bed.surrogate.option_aliases import RESULT_CONSERVE_KEY
from neuraldem.scenes.fluidized_bed.surrogate.options import RolloutOptions
from neuraldem.scenes.fluidized_bed.surrogate.rollout import (
    BedState,
    DataStepper,
    DivergenceLimits,
    ExtrapolationWarning,
    ModelStepper,
    initial_state,
    rollout,
)
from neuraldem.scenes.fluidized_bed.surrogate.rollout_run import RolloutFile, load_fb_checkpoint, run_rollout
from tests.helpers import run_module

pytestmark = pytest.mark.solver
TRAINED_VELOCITY = 1.228531  # fb_tiny's training split has this one velocity


def _run(ckpt: Path, fb_tiny_dataset: Path, out: Path, velocity: float = TRAINED_VELOCITY, **kwargs):
    return run_rollout(ckpt, velocity, kwargs.pop("steps", 50), out, fb_tiny_dataset.parent,
                       progress=False, **kwargs)


def test_rollout_of_50_steps_writes_hdf5_json_and_vtk(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path,
                                                     tmp_path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExtrapolationWarning)  # the trained velocity: no warning
        summary = _run(fb_tiny_checkpoint, fb_tiny_dataset, tmp_path, vtk_every=10, particles_every=10)
    assert summary["steps_done"] == 50 and summary["diverged_at"] is None and not summary["extrapolation"]
    assert summary["initial_state"] == "fb_tiny/sim_0000 snapshot 1"  # closest velocity, first by id; snapshot 1
    # (the first with a real last displacement)
    assert json.loads((tmp_path / "rollout.json").read_text())["steps_done"] == 50
    with RolloutFile(tmp_path / "rollout.h5") as r, BedFile(fb_tiny_dataset / "sims" / "sim_0000.h5") as f:
        alpha, u = r.grid_field("solid_fraction"), r.grid_field("fluid_velocity")
        assert alpha.shape == (51, 6, 1, 15) and u.shape == (51, 6, 1, 15, 3)
        np.testing.assert_allclose(r.times, np.round(np.arange(1, 52) * 0.01, 9), atol=1e-9)
        np.testing.assert_array_equal(alpha[0], f.solid_fraction(1).astype(np.float32))  # starts from the data
        assert np.isfinite(alpha).all() and not np.array_equal(alpha[1], alpha[0])
        assert r.diverged_at == -1 and r.total_volume == pytest.approx(float(f.particle_volumes.sum()))
        samples = r.f["samples/position"][()]
        assert samples.shape == (6, 300, 3)
        assert np.all(samples >= np.array(f.grid.lo) - 1e-7) and np.all(samples <= np.array(f.grid.hi) + 1e-7)
    # ParaView: a .pvd of 6 grid snapshots (every 10 steps) whose cells carry the stored fields in C order
    pvd = (tmp_path / "vtk" / "rollout_grid.pvd").read_text()
    assert pvd.count("<DataSet") == 6 and 'timestep="0.51"' in pvd
    mesh = meshio.read(tmp_path / "vtk" / "rollout_grid_0003.vtu")
    np.testing.assert_allclose(mesh.cell_data["solid_fraction"][0], alpha[30].ravel(), rtol=1e-6)
    centres = mesh.points[mesh.cells_dict["hexahedron"]].mean(axis=1)
    i, j, k = np.unravel_index(np.arange(90), (6, 1, 15))
    np.testing.assert_allclose(centres, (np.stack([i, j, k], 1) + 0.5) * np.array([0.004, 0.006, 0.004]),
                               atol=1e-9)
    assert (tmp_path / "vtk" / "rollout_particles.pvd").read_text().count("<DataSet") == 6


class Inject:
    """A stepper that spoils one field at one step (what a diverging model does)."""

    def __init__(self, inner, at: int, spoil):
        self.inner, self.at, self.spoil, self.dt, self.calls = inner, at, spoil, inner.dt, 0

    def step(self, state: BedState) -> BedState:
        self.calls += 1
        nxt = self.inner.step(state)
        if self.calls == self.at:
            self.spoil(nxt)
        return nxt


def _nan(s: BedState) -> None:
    s.fluid_velocity[2, 0, 7, 1] = np.nan


def _too_dense(s: BedState) -> None:
    s.solid_fraction[3, 0, 1] = 0.9


def _negative(s: BedState) -> None:
    s.solid_fraction[0, 0, 14] = -0.2


@pytest.mark.parametrize(("spoil", "message"), [
    (_nan, r"rollout diverged at step 7 \(t = 0\.070 s\): NaN/inf in the predicted fluid velocity \(1 values\)"),
    (_too_dense, (r"step 7 .*solid fraction 0\.9 above the maximum packing 0\.74 \(\+ tolerance 0\.05\) in cell "
                  r"\(3, 0, 1\)")),
    (_negative, r"step 7 .*solid fraction -0\.2 below 0 \(tolerance 0\.05\) in cell \(0, 0, 14\)"),
])
def test_divergence_detector_stops_at_the_step(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path, spoil, message,
                                               caplog: pytest.LogCaptureFixture):
    module = load_fb_checkpoint(fb_tiny_checkpoint)
    stepper = Inject(ModelStepper(module, TRAINED_VELOCITY), at=7, spoil=spoil)
    with BedFile(fb_tiny_dataset / "sims" / "sim_0000.h5") as f:
        r = rollout(stepper, initial_state(f, 0), 50, progress=False)
    assert r.diverged_at == 7 and r.steps_done == 6 and stepper.calls == 7  # stopped, states 0..6 kept
    assert np.isfinite(r.solid_fraction).all()
    assert re.search(message, r.message()), r.message()
    assert "rollout diverged at step 7" in caplog.text


def test_ground_truth_never_trips_the_detector(fb_tiny_dataset: Path):
    for sim in ("sim_0000", "sim_0001", "sim_0002"):
        with BedFile(fb_tiny_dataset / "sims" / f"{sim}.h5") as f:
            r = rollout(DataStepper(f), initial_state(f, 0), f.n_snapshots - 1, DivergenceLimits(), progress=False)
            assert r.diverged_at is None, (sim, r.message())
            np.testing.assert_array_equal(r.solid_fraction, f.solid_fraction())


def test_velocity_outside_the_trained_range_warns_and_is_flagged(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path,
                                                                 tmp_path: Path):
    with pytest.warns(ExtrapolationWarning, match=r"2\.1 m/s is outside the range the model was trained on "
                                                  r"\[1\.22853, 1\.22853\] m/s"):
        summary = _run(fb_tiny_checkpoint, fb_tiny_dataset, tmp_path, velocity=2.1, steps=3, vtk=False)
    assert summary["extrapolation"] and summary["trained_velocity_range"] == [TRAINED_VELOCITY] * 2
    assert summary["initial_state"] == "fb_tiny/sim_0002 snapshot 1"  # the closest velocity (2.04)
    with RolloutFile(tmp_path / "rollout.h5") as r:
        assert bool(r.attrs["extrapolation"]) and r.attrs["inlet_velocity"] == 2.1
    assert not (tmp_path / "vtk").exists()


def test_checkpoint_of_another_kind_or_scene_and_other_grid(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path,
                                                             tiny_checkpoint: Path, tmp_path: Path):
    with pytest.raises(DataError, match=r"is a 'hopper' checkpoint \(trained on 'hopper_tiny'\); a fluidized-bed "
                                        r"rollout or evaluation needs a fluidized_bed model.*experiment=fb"):
        _run(tiny_checkpoint, fb_tiny_dataset, tmp_path)

    def edited(change) -> Path:
        raw = torch.load(fb_tiny_checkpoint, weights_only=False)
        change(raw["hyper_parameters"]["metadata"])
        path = tmp_path / f"edited_{len(list(tmp_path.glob('*.ckpt')))}.ckpt"
        torch.save(raw, path)
        return path

    other_scene = edited(lambda m: m["scene"]["fluidized_bed"].update(n_particles=301))
    with pytest.raises(DataError, match=r"scene differs from .*fb_tiny \(in \['fluidized_bed\.n_particles'\]\)"):
        _run(other_scene, fb_tiny_dataset, tmp_path)
    other_grid = edited(lambda m: m["normalizer"].update(grid_shape=[12, 1, 30]))
    with pytest.raises(DataError, match=r"sim_0001\.h5: grid \[6, 1, 15\] cells .* differs from the model's grid "
                                        r"\[12, 1, 30\]"):
        _run(other_grid, fb_tiny_dataset, tmp_path, init=fb_tiny_dataset / "sims" / "sim_0001.h5")
    with pytest.raises(ConfigError, match=r"init_snapshot=99 is invalid: .*sim_0000\.h5 has snapshots 0 \.\. 20"):
        _run(fb_tiny_checkpoint, fb_tiny_dataset, tmp_path, init_snapshot=99)
    with pytest.raises(ConfigError, match=r"max_packing=1\.5 is invalid"):
        DivergenceLimits(max_packing=1.5)
    with pytest.raises(ConfigError, match=r"steps=0 is invalid"):
        _run(fb_tiny_checkpoint, fb_tiny_dataset, tmp_path, steps=0)


def test_cli(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path, tiny_checkpoint: Path, tmp_path: Path):
    env = {"NEURALDEM_DATA": str(fb_tiny_dataset.parent.parent)}
    proc = run_module("neuraldem.rollout", f"ckpt={fb_tiny_checkpoint}", "velocity=1.3", "steps=5",
                      f"hydra.run.dir={tmp_path / 'run'}", "progress=false", env=env)
    assert proc.returncode == 0, proc.stderr
    assert "rollout finished: 5 steps" in proc.stdout and "outside the trained range" in proc.stdout
    assert (tmp_path / "run" / "rollout.h5").is_file() and (tmp_path / "run" / "vtk" / "rollout_grid.pvd").is_file()
    bad = run_module("neuraldem.rollout", f"ckpt={tiny_checkpoint}", "velocity=1.3",
                     f"hydra.run.dir={tmp_path / 'bad'}", env=env)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert "is a hopper model, which has no time-stepping rollout" in bad.stderr
    typo = run_module("neuraldem.rollout", f"ckpt={fb_tiny_checkpoint}", "velocity=1.3", "rollout.conserve_volume=1",
                      f"hydra.run.dir={tmp_path / 'typo'}", env=env)
    assert typo.returncode == 2 and "rollout.conserve_volume=1 is invalid: must be true or false" in typo.stderr


def test_solid_volume_projection_holds_the_first_states_volume(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path,
                                                                tmp_path: Path):
    plain = _run(fb_tiny_checkpoint, fb_tiny_dataset, tmp_path / "plain", steps=20, vtk=False)
    kept = _run(fb_tiny_checkpoint, fb_tiny_dataset, tmp_path / "kept", steps=20, vtk=False,
                options=RolloutOptions(conserve_volume=True))
    assert kept[RESULT_CONSERVE_KEY] and not plain[RESULT_CONSERVE_KEY]
    with RolloutFile(tmp_path / "plain" / "rollout.h5") as a, RolloutFile(tmp_path / "kept" / "rollout.h5") as b:
        va = a.grid_field("solid_fraction").sum(axis=(1, 2, 3))
        vb = b.grid_field("solid_fraction").sum(axis=(1, 2, 3))
        assert b.f.attrs[RESULT_CONSERVE_KEY]
    np.testing.assert_allclose(vb, vb[0], rtol=1e-5)  # float32 storage
    assert np.max(np.abs(va / va[0] - 1)) > 1e-3  # the untrained tiny model alone does not conserve it


def test_the_recipe_options_conserve_to_round_off_and_keep_mixing_bounded(fb_tiny_flux_checkpoint: Path,
                                                                       fb_tiny_dataset: Path):
    from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
    from neuraldem.scenes.fluidized_bed.surrogate.rollout import ModelStepper, initial_state, rollout
    from neuraldem.scenes.fluidized_bed.surrogate.rollout_run import load_fb_checkpoint

    module = load_fb_checkpoint(fb_tiny_flux_checkpoint)
    assert module.stability.mixing == "advect" and module.stability.conserve_volume and module.net.noise_dim == 4
    with BedFile(sorted((fb_tiny_dataset / "sims").glob("*.h5"))[0]) as f:
        state = initial_state(f)
        runs = [rollout(ModelStepper(module, TRAINED_VELOCITY, seed), state, 40, progress=False) for seed in (0, 1)]
    for r in runs:
        assert r.diverged_at is None
        volume = r.solid_fraction.astype(np.float64).reshape(len(r.times), -1).sum(axis=1)
        np.testing.assert_allclose(volume, float(np.sum(state.solid_fraction)), rtol=2e-6)  # float32 round-off
        assert r.mixing.min() >= 0.0 and r.mixing.max() <= 1.0
        assert r.solid_fraction.max() <= module.norm.solid_fraction_max * (1 + 1e-5)  # the packing cap holds
    assert np.abs(runs[0].solid_fraction - runs[1].solid_fraction).max() > 1e-6  # two members differ
    same = rollout(ModelStepper(module, TRAINED_VELOCITY, 0), state, 40, progress=False)
    np.testing.assert_array_equal(same.solid_fraction, runs[0].solid_fraction)  # a seed reproduces its member


def test_a_projection_short_of_the_volume_is_named(fb_tiny_flux_checkpoint: Path, fb_tiny_dataset: Path,
                                                  monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture):
    """The rollout restores the volume after the (float32) projection; more than round-off to restore means the
    projection fell short, and the rescale then moves capped cells past the cap: the step says so."""
    import neuraldem.scenes.fluidized_bed.surrogate.autoregressive as ar
    from neuraldem.scenes.fluidized_bed.dataset.store import BedFile
    from neuraldem.scenes.fluidized_bed.surrogate.rollout import ModelStepper, initial_state
    from neuraldem.scenes.fluidized_bed.surrogate.rollout_run import load_fb_checkpoint

    module = load_fb_checkpoint(fb_tiny_flux_checkpoint)
    with BedFile(sorted((fb_tiny_dataset / "sims").glob("*.h5"))[0]) as f:
        state = initial_state(f)
    with caplog.at_level(logging.WARNING, logger="neuraldem.scenes.fluidized_bed.surrogate.rollout"):
        ModelStepper(module, TRAINED_VELOCITY, 0).step(state)
        assert "off the volume" not in caplog.text
        project = ar.project_volume
        monkeypatch.setattr(ar, "project_volume", lambda fluid, norm, volume: project(fluid, norm, 0.9 * volume))
        ModelStepper(module, TRAINED_VELOCITY, 0).step(state)
    assert "the projected solid volume is -10 % off the volume to keep" in caplog.text


def test_advection_correction_reaches_the_mixing_and_is_recorded(fb_tiny_flux_checkpoint: Path,
                                                                  fb_tiny_dataset: Path, tmp_path: Path):
    """`rollout.advection_correction=X` (of `evaluate rollout` and `evaluate`) changes only how the
    tagged solid is carried: the solid fraction is the same step for step, the mixing field is not, and the
    summary says which correction ran."""
    import h5py

    runs = {}
    for corr in (0.0, 1.0):
        summary = _run(fb_tiny_flux_checkpoint, fb_tiny_dataset, tmp_path / str(corr), steps=20, vtk=False,
                       options=RolloutOptions(advection_correction=corr))
        assert summary["advection_correction"] == corr
        with h5py.File(tmp_path / str(corr) / "rollout.h5") as f:
            runs[corr] = {k: f["snapshots"][k][...] for k in ("solid_fraction", "mixing")}
    np.testing.assert_array_equal(runs[0.0]["solid_fraction"], runs[1.0]["solid_fraction"])
    assert np.abs(runs[0.0]["mixing"] - runs[1.0]["mixing"]).max() > 1e-6


def test_bad_rollout_requests_end_in_one_line(fb_tiny_checkpoint: Path, fb_tiny_dataset: Path, tmp_path: Path):
    env = {"NEURALDEM_DATA": str(fb_tiny_dataset.parent.parent)}
    cases = [("init_snapshot=999", "init_snapshot=999 is invalid:", "e.g. init_snapshot=1"),
             ("rollout.mixing=advect", "rollout.mixing=advect needs a model trained with the solids flux",
              "rollout.mixing=absolute"),
             ("rollout.mixing=stir", "rollout.mixing=stir is invalid", "must be one of absolute, advect"),
             ("rollout.mirror_alternate=maybe", "rollout.mirror_alternate=maybe is invalid", "must be true or false"),
             ("rollout.rollout_noise=-1", "rollout.rollout_noise=-1 is invalid", "must be a number in [0, 10]"),
             ("rollout.advection_correction=2", "rollout.advection_correction=2 is invalid",
              "must be a number in [0, 1]")]
    for i, (override, message, fix) in enumerate(cases):
        proc = run_module("neuraldem.rollout", f"ckpt={fb_tiny_checkpoint}", f"velocity={TRAINED_VELOCITY}", "steps=3",
                          override,
                          f"hydra.run.dir={tmp_path / str(i)}", "progress=false", env=env)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert message in proc.stderr and fix in proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr


def test_mirror_alternation_steps_every_second_state_in_the_mirror_image(fb_tiny_flux_checkpoint: Path,
                                                                           fb_tiny_dataset: Path):
    """With mirror_alternate the 1st, 3rd, ... steps are the net's plain step and the 2nd, 4th, ... the mirror
    image of the net's step from the mirrored state; the solid volume still holds to round-off and the mixing
    stays in [0, 1]. The untrained tiny net is not mirror-symmetric, so the alternation must change step 2."""
    from neuraldem.scenes.fluidized_bed.surrogate.rollout import mirror_state

    module = load_fb_checkpoint(fb_tiny_flux_checkpoint)
    lo_x, hi_x = module.norm.box_lo[0], module.norm.box_hi[0]
    with BedFile(sorted((fb_tiny_dataset / "sims").glob("*.h5"))[0]) as f:
        state = initial_state(f)
    twice = mirror_state(mirror_state(state, lo_x, hi_x), lo_x, hi_x)
    for name in ("positions", "displacement", "fluid_velocity", "solid_fraction", "mixing", "solids_flux"):
        np.testing.assert_allclose(getattr(twice, name), getattr(state, name), atol=1e-12)
    alt = ModelStepper(module, TRAINED_VELOCITY, 0, options=RolloutOptions(mirror_alternate=True))
    plain, by_hand = ModelStepper(module, TRAINED_VELOCITY, 0), ModelStepper(module, TRAINED_VELOCITY, 0)
    first = alt.step(state)
    np.testing.assert_array_equal(first.solid_fraction, plain.step(state).solid_fraction)
    second = alt.step(first)
    by_hand.step(state)  # the same draws of latent noise and particle samples as the alternating stepper's
    expected = mirror_state(by_hand.step(mirror_state(first, lo_x, hi_x)), lo_x, hi_x)
    for name in ("solid_fraction", "fluid_velocity", "mixing", "solids_flux", "positions"):
        np.testing.assert_allclose(getattr(second, name), getattr(expected, name), rtol=1e-6, atol=1e-9)
    assert np.abs(second.solid_fraction - plain.step(first).solid_fraction).max() > 1e-6
    r = rollout(ModelStepper(module, TRAINED_VELOCITY, 0, options=RolloutOptions(mirror_alternate=True)), state, 30,
                progress=False)
    volume = r.solid_fraction.astype(np.float64).reshape(len(r.times), -1).sum(axis=1)
    np.testing.assert_allclose(volume, float(np.sum(state.solid_fraction)), rtol=2e-6)
    assert r.diverged_at is None and r.mixing.min() >= 0.0 and r.mixing.max() <= 1.0


def test_rollout_noise_perturbs_what_the_net_reads_and_nothing_else(fb_tiny_flux_checkpoint: Path,
                                                                    fb_tiny_dataset: Path):
    """The net reads each state plus noise of rollout_noise x its running one-step error; the projection and the
    advection act on the clean state, so even a large noise keeps the solid volume to round-off, the packing
    cap and the mixing in [0, 1]. A seed reproduces its rollout; 0 is the plain rollout."""
    module = load_fb_checkpoint(fb_tiny_flux_checkpoint)
    assert float(module.step_error_fluid.abs().sum()) > 0  # trained: the running error exists
    with BedFile(sorted((fb_tiny_dataset / "sims").glob("*.h5"))[0]) as f:
        state = initial_state(f)
    plain = rollout(ModelStepper(module, TRAINED_VELOCITY, 0), state, 30, progress=False)
    off = rollout(ModelStepper(module, TRAINED_VELOCITY, 0, options=RolloutOptions(rollout_noise=0.0)), state, 30,
                  progress=False)
    np.testing.assert_array_equal(off.solid_fraction, plain.solid_fraction)
    for scale in (1.0, 10.0):
        noisy = RolloutOptions(rollout_noise=scale)
        runs = [rollout(ModelStepper(module, TRAINED_VELOCITY, 0, options=noisy), state, 30, progress=False)
                for _ in range(2)]
        np.testing.assert_array_equal(runs[0].solid_fraction, runs[1].solid_fraction)
        r = runs[0]
        assert r.diverged_at is None and np.abs(r.solid_fraction - plain.solid_fraction).max() > 0
        volume = r.solid_fraction.astype(np.float64).reshape(len(r.times), -1).sum(axis=1)
        np.testing.assert_allclose(volume, float(np.sum(state.solid_fraction)), rtol=2e-6)
        assert r.mixing.min() >= 0.0 and r.mixing.max() <= 1.0
        assert r.solid_fraction.max() <= module.norm.solid_fraction_max * (1 + 1e-5)
    # what the net read: the state plus noise of 3 x the running error, per channel
    read, latents = [], module.net.latents
    module.net.latents = lambda x, **kw: read.append(x.grid.clone()) or latents(x, **kw)
    stepper = ModelStepper(module, TRAINED_VELOCITY, 0, options=RolloutOptions(rollout_noise=3.0))
    clean = torch.from_numpy(grid_input(module.norm, state.fluid_velocity, state.solid_fraction, state.solids_flux))
    stepper.step(state)
    spread = (read[0][0] - clean.float()).flatten(1).std(dim=1)
    np.testing.assert_allclose(spread.numpy(), 3.0 * module.step_error_fluid.numpy(), rtol=0.35)


def test_rollout_noise_names_a_checkpoint_without_its_running_error(fb_tiny_flux_checkpoint: Path):
    module = load_fb_checkpoint(fb_tiny_flux_checkpoint)
    for name in ("particles", "fluid", "mixing"):
        getattr(module, f"step_error_{name}").zero_()
    with pytest.raises(ConfigError, match="rollout.rollout_noise=1 needs the model's running one-step error"):
        ModelStepper(module, TRAINED_VELOCITY, 0, options=RolloutOptions(rollout_noise=1.0))
    with pytest.raises(ConfigError, match="rollout.rollout_noise=-0.5 is invalid"):
        ModelStepper(module, TRAINED_VELOCITY, 0, options=RolloutOptions(rollout_noise=-0.5))


def test_particles_nobody_keeps_are_decoded_only_where_the_next_step_reads_them(fb_tiny_flux_checkpoint: Path,
                                                                                fb_tiny_dataset: Path):
    """A rollout keeps the particles every `particles_every` steps; in between an ONNX stepper decodes the
    displacement only of the particles the next step's encoder reads (a quarter of them on the shipped model). The
    rollout is the one of decoding them all, to round-off, and its kept samples are whole."""
    module = load_fb_checkpoint(fb_tiny_flux_checkpoint)
    with BedFile(sorted((fb_tiny_dataset / "sims").glob("*.h5"))[0]) as f:
        state = initial_state(f)
    every, partial = ModelStepper(module, TRAINED_VELOCITY, 0), ModelStepper(module, TRAINED_VELOCITY, 0)
    a, b = every.step(state), partial.step(state, all_particles=False)
    assert a.decoded is None and b.decoded is not None and 0 < len(b.decoded) < len(b.positions)
    np.testing.assert_array_equal(a.positions, b.positions)  # the same draws
    np.testing.assert_allclose(b.displacement[b.decoded], a.displacement[b.decoded], rtol=1e-5, atol=1e-9)
    graph = partial.net.encoders["particles"].graph(torch.from_numpy(
        module.norm.positions(b.positions).astype(np.float32))[None])
    assert set(graph.particles_read().tolist()) <= set(b.decoded.tolist())  # what the next step reads is there
    with pytest.raises(ValueError, match="can only be stepped by the stepper that made it"):
        ModelStepper(module, TRAINED_VELOCITY, 0).step(b)
    assert not every.decodes_on_demand  # torch steps decode every particle: bit for bit the reference
    on_demand = ModelStepper(module, TRAINED_VELOCITY, 0, runtime="onnx")
    assert on_demand.decodes_on_demand
    full = rollout(ModelStepper(module, TRAINED_VELOCITY, 0, runtime="onnx"), state, 12, particles_every=1,
                   progress=False)
    lean = rollout(on_demand, state, 12, particles_every=5, progress=False)
    np.testing.assert_allclose(lean.solid_fraction, full.solid_fraction, atol=1e-5)
    np.testing.assert_allclose(lean.mixing, full.mixing, atol=1e-5)
    assert lean.positions.shape == (3, *full.positions.shape[1:])  # states 0, 5, 10: every particle
    np.testing.assert_allclose(lean.displacement, full.displacement[::5], rtol=1e-4, atol=1e-8)


def test_the_onnx_step_is_the_torch_step_to_round_off(fb_tiny_flux_checkpoint: Path, fb_tiny_dataset: Path,
                                                      monkeypatch: pytest.MonkeyPatch, caplog):
    module = load_fb_checkpoint(fb_tiny_flux_checkpoint)
    with BedFile(sorted((fb_tiny_dataset / "sims").glob("*.h5"))[0]) as f:
        state = initial_state(f)
    runs = {}
    for runtime in ("torch", "onnx"):
        stepper = ModelStepper(module, TRAINED_VELOCITY, 0, runtime=runtime)
        assert stepper.runtime == runtime
        runs[runtime] = rollout(stepper, state, 5, progress=False)
    for name in ("solid_fraction", "mixing", "fluid_velocity"):
        np.testing.assert_allclose(getattr(runs["onnx"], name), getattr(runs["torch"], name), atol=1e-4)
    with pytest.raises(ConfigError, match="runtime='fast' is invalid"):
        ModelStepper(module, TRAINED_VELOCITY, 0, runtime="fast")
    import neuraldem.scenes.fluidized_bed.surrogate.rollout as rollout_module

    def refuse(*args, **kwargs):
        raise DataError("cannot export here")

    monkeypatch.setattr(rollout_module, "OnnxOperator", refuse)
    monkeypatch.setattr(rollout_module, "_ONNX_NETS", type(rollout_module._ONNX_NETS)())
    with caplog.at_level(logging.WARNING, logger="neuraldem.scenes.fluidized_bed.surrogate.rollout"):
        assert ModelStepper(module, TRAINED_VELOCITY, 0, runtime="auto").runtime == "torch"  # falls back, says so
    assert "the rollout steps in torch: the ONNX export failed" in caplog.text
    with pytest.raises(DataError, match="cannot export here"):
        ModelStepper(module, TRAINED_VELOCITY, 0, runtime="onnx")
