"""The multi-branch operator's calls through ONNX Runtime answer as the torch net does (to round-off), are exported
once per weights and grid, and a runtime that cannot run is one line naming the option and the fix."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

from neuraldem.errors import ConfigError
from neuraldem.models.multi_branch_operator import MultiBranchOperator, OperatorInputs
from neuraldem.models.operator_onnx import OnnxOperator, resolve_runtime, weights_key
from tests.models.nets import activate_modulations

GRID = (4, 1, 6)


def small_net(noise_dim: int = 0) -> MultiBranchOperator:
    torch.manual_seed(0)
    net = MultiBranchOperator(n_scalars=1, particle_channels=3, fluid_channels=7, mixing_channels=1, dim=16,
                              num_heads=2, cond_dim=16, n_supernodes=6, radius=0.3, max_neighbours=8,
                              patch_size=(2, 1, 2), noise_dim=noise_dim)
    return activate_modulations(net).eval()


@pytest.mark.parametrize(("off_branches", "noise_dim"), [(False, 0), (True, 0), (True, 3)])
def test_latents_and_decodes_equal_the_torch_nets(tmp_path: Path, off_branches: bool, noise_dim: int):
    net = small_net(noise_dim)
    onnx = OnnxOperator(net, tmp_path, off_branches=off_branches)
    x = net.example_inputs(batch_size=1, n_particles=40, grid_shape=GRID, generator=torch.Generator().manual_seed(3))
    if noise_dim:
        x.noise = torch.randn(1, noise_dim, generator=torch.Generator().manual_seed(4))
    with torch.no_grad():
        want_tokens, want_cond = net.latents(x, off_branches=off_branches)
        tokens, cond = onnx.latents(x, off_branches=off_branches)
        queries = {b: x.query_pos[b] for b in onnx.branches}
        want, got = net.decode(want_tokens, want_cond, queries), onnx.decode(tokens, cond, queries, chunk_size=7)
    assert set(tokens) == set(want_tokens) == set(onnx.branches)
    assert onnx.branches == (("particles", "fluid", "mixing") if off_branches else ("particles", "fluid"))
    torch.testing.assert_close(cond, want_cond, atol=1e-5, rtol=1e-5)
    for b in onnx.branches:
        torch.testing.assert_close(tokens[b], want_tokens[b], atol=1e-4, rtol=1e-4)
        assert got[b].shape == want[b].shape
        torch.testing.assert_close(got[b], want[b], atol=1e-4, rtol=1e-4)  # chunked: the same answer
    if not off_branches:
        with pytest.raises(ValueError, match="main branches alone"):
            onnx.latents(x, off_branches=True)


@pytest.mark.parametrize("off_branches", [False, True])
def test_the_grid_decoded_with_the_latents_is_the_decoders_answer(tmp_path: Path, off_branches: bool):
    """The latents call also decodes the grid branches at the cell centres; a decode at exactly those positions,
    from those tokens, answers from it, and any other decode asks the decoder."""
    from neuraldem.models.modules.patch_embedding import cell_centres

    net = small_net()
    onnx = OnnxOperator(net, tmp_path, off_branches=off_branches)
    x = net.example_inputs(batch_size=1, n_particles=40, grid_shape=GRID, generator=torch.Generator().manual_seed(5))
    centres = cell_centres(GRID)[None]
    with torch.no_grad():
        want_tokens, want_cond = net.latents(x, off_branches=off_branches)
        tokens, cond = onnx.latents(x, off_branches=off_branches)
        grids = onnx.grid_branches
        assert grids == (("fluid", "mixing") if off_branches else ("fluid",))
        want = net.decode(want_tokens, want_cond, {b: centres for b in grids})
        calls = []
        for b in grids:  # count the decoder sessions' runs
            run = onnx.sessions[b].run
            onnx.sessions[b] = type("Counted", (), {"run": lambda self, *a, run=run, b=b: calls.append(b) or run(*a)})()
        got = onnx.decode(tokens, cond, {b: centres.clone() for b in grids})
        assert calls == []  # answered by the latents call
        for b in grids:
            torch.testing.assert_close(got[b], want[b], atol=1e-4, rtol=1e-4)
        shifted = onnx.decode(tokens, cond, {"fluid": centres * 0.5})["fluid"]
        other = {k: v.clone() for k, v in tokens.items()}  # equal tokens, not the latents call's own
        again = onnx.decode(other, cond, {"fluid": centres})["fluid"]
    assert calls == ["fluid", "fluid"]
    torch.testing.assert_close(shifted, net.decode(want_tokens, want_cond, {"fluid": centres * 0.5})["fluid"],
                               atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(again, want["fluid"], atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize("batch", [1, 3])
def test_an_export_with_a_batch_axis_answers_each_member_as_alone(tmp_path: Path, batch: int):
    """One call for several states (`batch_axis=True`): each member's tokens, grid and decoded particles are its own
    call's (the supernodes of its own call given), to round-off; the export is kept apart from the batch-of-one
    one."""
    from neuraldem.models.modules.patch_embedding import cell_centres

    net = small_net(noise_dim=3)
    members = [net.example_inputs(batch_size=1, n_particles=40, grid_shape=GRID,
                                  generator=torch.Generator().manual_seed(10 + i)) for i in range(batch)]
    encoder = net.encoders["particles"]
    for i, x in enumerate(members):
        x.supernode_idx = encoder.graph(x.particle_pos).supernode_idx
        x.noise = torch.randn(1, 3, generator=torch.Generator().manual_seed(20 + i))
    stacked = OperatorInputs(*(torch.cat([getattr(x, k) for x in members]) for k in
                               ("particle_pos", "particle_features", "grid", "mixing_grid", "scalars")),
                             supernode_idx=torch.cat([x.supernode_idx for x in members]),
                             noise=torch.cat([x.noise for x in members]))
    batched = OnnxOperator(net, tmp_path, batch_axis=True)
    centres = cell_centres(GRID)[None]
    queries = torch.rand(batch, 25, 3, generator=torch.Generator().manual_seed(6))
    with torch.no_grad():
        tokens, cond = batched.latents(stacked)
        grids = batched.decode(tokens, cond, {b: centres.expand(batch, -1, -1) for b in batched.grid_branches})
        particles = batched.decode(tokens, cond, {"particles": queries}, chunk_size=10)["particles"]
        for i, x in enumerate(members):
            want_tokens, want_cond = net.latents(x)
            want = net.decode(want_tokens, want_cond, {"fluid": centres, "mixing": centres,
                                                       "particles": queries[i:i + 1]})
            torch.testing.assert_close(cond[i:i + 1], want_cond, atol=1e-5, rtol=1e-5)
            for b in batched.branches:
                torch.testing.assert_close(tokens[b][i:i + 1], want_tokens[b], atol=1e-4, rtol=1e-4)
            for b in batched.grid_branches:
                torch.testing.assert_close(grids[b][i:i + 1], want[b], atol=1e-4, rtol=1e-4)
            torch.testing.assert_close(particles[i:i + 1], want["particles"], atol=1e-4, rtol=1e-4)
    assert [p.name for p in tmp_path.iterdir()] == [weights_key(net, True, GRID, batch_axis=True)]
    assert weights_key(net, True, GRID, batch_axis=True) != weights_key(net, True, GRID)


def test_the_export_is_cached_per_weights_and_grid(tmp_path: Path):
    net = small_net()
    x = net.example_inputs(batch_size=1, n_particles=30, grid_shape=GRID)
    first = OnnxOperator(net, tmp_path, off_branches=False)
    first.latents(x, off_branches=False)
    folders = sorted(p.name for p in tmp_path.iterdir())
    assert folders == [weights_key(net, False, GRID)] and (tmp_path / folders[0] / "checked.json").is_file()
    stamp = (tmp_path / folders[0] / "latents.onnx").stat().st_mtime_ns
    OnnxOperator(net, tmp_path, off_branches=False).prepare(GRID)  # read back, not exported again
    assert (tmp_path / folders[0] / "latents.onnx").stat().st_mtime_ns == stamp
    with torch.no_grad():
        next(net.parameters()).add_(1.0)  # other weights: another export
    assert weights_key(net, False, GRID) != folders[0]
    assert weights_key(net, False, (4, 1, 8)) != weights_key(net, False, GRID)


def test_a_damaged_export_names_the_folder_to_delete(tmp_path: Path):
    from neuraldem.errors import DataError

    net = small_net()
    OnnxOperator(net, tmp_path, off_branches=False).prepare(GRID)
    folder = tmp_path / weights_key(net, False, GRID)
    (folder / "latents.onnx").write_bytes(b"not a model")
    with pytest.raises(DataError, match=f"delete {folder}"):
        OnnxOperator(net, tmp_path, off_branches=False).prepare(GRID)


def test_runtime_values_and_a_missing_runtime(monkeypatch: pytest.MonkeyPatch):
    assert resolve_runtime("torch") == "torch" and resolve_runtime("auto") == "onnx"
    with pytest.raises(ConfigError, match="runtime='tensorrt' is invalid: choose one of torch, onnx, auto"):
        resolve_runtime("tensorrt")
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # as on a machine without it
    assert resolve_runtime("auto") == "torch"
    with pytest.raises(ConfigError, match="runtime=onnx needs ONNX Runtime") as err:
        resolve_runtime("onnx")
    assert "pip install onnxruntime" in str(err.value)
