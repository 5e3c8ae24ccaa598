"""The multi-branch operator's inference calls (`latents`, `decode`) answered by ONNX Runtime.

Why: a small net is dominated by the cost of each call, not by arithmetic. The shipped bed model (width 32,
16 supernodes, 60 grid patches) makes thousands of small torch calls per rollout step, each costing more in
dispatch than in arithmetic; ONNX Runtime runs the same graph with far less per node (the bed's whole rollout
step, 0.56 -> 0.31 s per simulated second at one thread: results/fluidized_bed/speed/fb_speed.md, its runtime
column). The particle graph (torch_cluster's radius search) is no ONNX operator: it stays in torch and the
exported encoder takes its edges as inputs.

`OnnxOperator` stands in for a `MultiBranchOperator` wherever a caller only runs `latents` and `decode` (a
rollout step). Its answers are the torch net's to float32 round-off (checked at export, `EXPORT_TOLERANCE`), not
bit for bit: the supernode mean is summed in another order. The exported files are cached by a hash of the
weights, so one export (a few seconds) serves every later process.
"""

from __future__ import annotations

import hashlib
import json
import logging
import warnings
import weakref
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from neuraldem.models.modules.patch_embedding import cell_centres
from neuraldem.models.modules.supernode_pooling import ParticleGraph
from neuraldem.models.multi_branch_operator import MultiBranchOperator, OperatorInputs
from neuraldem.models.onnx_runtime import OPSET, check_threads, installed, require_onnxruntime

log = logging.getLogger(__name__)

EXPORT_TOLERANCE = 1e-3  # largest difference (model units) of the exported net's answers from the torch net's
RUNTIMES = ("torch", "onnx", "auto")  # auto: onnx where ONNX Runtime is installed


def resolve_runtime(runtime: str, key: str = "runtime") -> str:
    """"torch" or "onnx" for a requested runtime (auto: onnx when ONNX Runtime imports)."""
    from neuraldem.errors import ConfigError

    if runtime not in RUNTIMES:
        raise ConfigError(f"{key}={runtime!r} is invalid: choose one of {', '.join(RUNTIMES)}",
                          f"e.g. {key}=auto (ONNX Runtime where it is installed, else torch)")
    if runtime == "auto":
        return "onnx" if installed() else "torch"
    if runtime == "onnx":
        require_onnxruntime(key)
    return runtime


class _Latents(nn.Module):
    """`net.latents` with the particle graph given: the supernode mean as a product with the edges' one-hot
    matrix (ONNX has no scatter-add the exporter maps index_add_ to). With `grid_shape`, the grid branches are
    also decoded at the grid's cell centres in the same call (what every rollout step asks for next: one session
    run instead of two, and the query embedding of the fixed centres folded into constants at export)."""

    def __init__(self, net: MultiBranchOperator, off_branches: bool, grid_shape: tuple[int, ...] | None = None):
        super().__init__()
        self.net, self.off_branches = net, off_branches
        self.grid_shape = grid_shape

    def forward(self, particle_pos: torch.Tensor, particle_features: torch.Tensor, supernode_idx: torch.Tensor,
                edges: torch.Tensor, grid: torch.Tensor, mixing_grid: torch.Tensor, scalars: torch.Tensor,
                noise: torch.Tensor) -> tuple[torch.Tensor, ...]:
        net = self.net
        cond = net.conditioner(scalars)
        if net.noise_embed is not None:
            cond = cond + net.noise_embed(noise)
        tokens = {}
        if net.particle_branch:
            tokens["particles"] = self._pool(particle_pos, particle_features, supernode_idx, edges)
        tokens["fluid"] = net.encoders["fluid"](grid)
        if self.off_branches:
            tokens["mixing"] = net.encoders["mixing"](mixing_grid)
        for block in [*net.encoder_blocks, *net.approximator_blocks, *net.decoder_blocks]:
            tokens = block(tokens, cond, self.off_branches)
        grids = ()
        if self.grid_shape is not None:
            centres = cell_centres(self.grid_shape).unsqueeze(0).expand(grid.shape[0], -1, -1)
            decoded = net.decode(tokens, cond, {b: centres for b in self.grid_branches()})
            grids = tuple(decoded[b] for b in self.grid_branches())
        return (*(tokens[b] for b in self.branches()), cond, *grids)

    def branches(self) -> tuple[str, ...]:
        return self.net.main_branches + (("mixing",) if self.off_branches else ())

    def grid_branches(self) -> tuple[str, ...]:
        return tuple(b for b in self.branches() if b != "particles")

    def _pool(self, positions: torch.Tensor, features: torch.Tensor, supernode_idx: torch.Tensor,
              edges: torch.Tensor) -> torch.Tensor:
        messages = self.net.encoders["particles"].messages(positions, features, ParticleGraph(supernode_idx, edges))
        batch, n_supernodes = supernode_idx.shape
        tokens = torch.arange(batch * n_supernodes, device=positions.device)
        one_hot = (edges[0].unsqueeze(1) == tokens.unsqueeze(0)).to(messages.dtype)  # (E, B * M)
        summed = one_hot.transpose(0, 1) @ messages
        counts = one_hot.sum(0).clamp(min=1.0).unsqueeze(-1)
        return (summed / counts).reshape(batch, n_supernodes, -1)


class _Decoder(nn.Module):
    def __init__(self, net: MultiBranchOperator, branch: str):
        super().__init__()
        self.decoder = net.decoders[branch]

    def forward(self, tokens: torch.Tensor, query_pos: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        return self.decoder(tokens, query_pos, cond)


def weights_key(net: MultiBranchOperator, off_branches: bool, grid_shape: tuple[int, ...],
                batch_axis: bool = False) -> str:
    """Hash of the weights, the net's shape, the grid, what is exported and the code that computes it (every module
    of `neuraldem.models`): the cache key of the exported files, so a changed net code is exported anew."""
    h = hashlib.sha256()
    for source in sorted(Path(__file__).parent.rglob("*.py")):
        h.update(source.read_bytes())
    for name, value in sorted(net.state_dict().items()):
        h.update(name.encode())
        h.update(value.detach().cpu().contiguous().numpy().tobytes())
    h.update(json.dumps({"off_branches": off_branches, "opset": OPSET, "noise_dim": net.noise_dim,
                         "particle_branch": net.particle_branch, "grid": list(grid_shape),
                         "torch": torch.__version__, **({"batch_axis": True} if batch_axis else {})}).encode())
    return h.hexdigest()[:24]


def _export(module: nn.Module, inputs: Mapping[str, torch.Tensor], outputs: list[str], path: Path,
            dynamic: Mapping[str, Mapping[int, str]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the tracer's notes on shape-dependent branches: the check decides
        torch.onnx.export(module.eval(), tuple(inputs.values()), str(tmp), input_names=list(inputs),
                          output_names=outputs, dynamic_axes={**dynamic}, opset_version=OPSET, dynamo=False)
    tmp.replace(path)


class OnnxOperator:
    """A `MultiBranchOperator`'s `latents` and `decode`, answered by ONNX Runtime sessions (exported into a
    folder under `folder` on the first call, for the grid of that call, and checked against the torch net).
    `batch_axis`: the calls exported for any batch size, not for a batch of one (a rollout steps a batch of one:
    one for several rollouts is measured in results/fluidized_bed/speed/fb_batch.md)."""

    def __init__(self, net: MultiBranchOperator, folder: Path, off_branches: bool = True, threads: int = 1,
                 batch_axis: bool = False):

        ort = require_onnxruntime()
        # held weakly: a cache of these per net (a rollout's) must not keep the net alive
        self._net = weakref.ref(net.eval())
        self.noise_dim, self.particle_branch = net.noise_dim, net.particle_branch
        self.main_branches, self.off_branches = net.main_branches, off_branches
        latents = _Latents(net, off_branches)
        self.branches = latents.branches()  # decodable: an off-branch needs its own tokens
        self.grid_branches = latents.grid_branches()
        # the grid branches decoded at the cell centres by the last `latents` call: {branch: (its tokens, out)}
        self._grid_out: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}
        self._centres: torch.Tensor | None = None
        self.root, self.threads, self._ort = Path(folder), check_threads(threads), ort
        self.sessions: dict[str, Any] = {}
        self.grid_shape: tuple[int, ...] | None = None  # exported for the first grid it is given
        self.batch_axis = batch_axis

    @property
    def torch_net(self) -> MultiBranchOperator:
        net = self._net()
        if net is None:
            raise RuntimeError("the torch net of this ONNX export is gone")
        return net

    @property
    def encoders(self) -> nn.ModuleDict:
        return self.torch_net.encoders

    def prepare(self, grid_shape: tuple[int, ...]) -> None:
        """Export for this grid (once per weights and grid: cached in the folder) and open the sessions."""
        from neuraldem.errors import DataError

        ort = self._ort
        self.folder = self.root / weights_key(self.torch_net, self.off_branches, grid_shape, self.batch_axis)
        if not (self.folder / "checked.json").exists():
            self._export_and_check(ort, grid_shape)
        options = ort.SessionOptions()
        options.intra_op_num_threads = self.threads
        options.inter_op_num_threads = 1
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        try:
            self.sessions = {name: ort.InferenceSession(str(self.folder / f"{name}.onnx"), options,
                                                        providers=["CPUExecutionProvider"])
                             for name in ("latents", *self.branches)}
        except Exception as err:  # noqa: BLE001 - a damaged cache file of any kind
            raise DataError(f"{self.folder}: an exported net could not be read ({type(err).__name__})",
                            f"delete {self.folder} (it is exported again)") from None
        # the exporter drops the inputs a net does not read (noise of a deterministic net, ...)
        self.latent_inputs = [i.name for i in self.sessions["latents"].get_inputs()]
        self.grid_shape = grid_shape
        self._centres = cell_centres(grid_shape)

    # ---- export
    def _example(self, grid_shape: tuple[int, ...]) -> dict[str, torch.Tensor]:
        g = torch.Generator().manual_seed(0)
        # a batch axis is traced from a batch of two: a batch of one could be folded into constants
        x = self.torch_net.example_inputs(batch_size=2 if self.batch_axis else 1, n_particles=64,
                                          grid_shape=grid_shape, generator=g)
        return self._feed_tensors(x)

    def _feed_tensors(self, x: OperatorInputs) -> dict[str, torch.Tensor]:
        batch = x.grid.shape[0]
        if self.particle_branch:
            graph = x.particle_graph or self.encoders["particles"].graph(x.particle_pos, x.supernode_idx)
            supernode_idx, edges = graph.supernode_idx, graph.edges
        else:
            supernode_idx = torch.zeros(batch, 1, dtype=torch.long)
            edges = torch.zeros(2, 1, dtype=torch.long)
        noise = x.noise if x.noise is not None else torch.zeros(batch, max(self.noise_dim, 1))
        return {"particle_pos": x.particle_pos, "particle_features": x.particle_features,
                "supernode_idx": supernode_idx, "edges": edges, "grid": x.grid, "mixing_grid": x.mixing_grid,
                "scalars": x.scalars, "noise": noise}

    def _export_and_check(self, ort: Any, grid_shape: tuple[int, ...]) -> None:
        from neuraldem.errors import DataError

        feed = self._example(grid_shape)
        latents = _Latents(self.torch_net, self.off_branches, grid_shape)
        outputs = [*self.branches, "cond", *self._grid_names()]
        dynamic: dict[str, dict[int, str]] = {"particle_pos": {1: "particles"}, "particle_features": {1: "particles"},
                                              "edges": {1: "edges"}}
        if self.batch_axis:
            for name in feed:
                if name != "edges":
                    dynamic.setdefault(name, {})[0] = "batch"
        _export(latents, feed, outputs, self.folder / "latents.onnx", dynamic)
        with torch.no_grad():
            tokens, cond = self.torch_net.latents(OperatorInputs(
                feed["particle_pos"], feed["particle_features"], feed["grid"], feed["mixing_grid"],
                feed["scalars"], supernode_idx=feed["supernode_idx"], noise=feed["noise"] if self.noise_dim
                else None), off_branches=self.off_branches)
            batch = cond.shape[0]
            centres = cell_centres(grid_shape)[None].expand(batch, -1, -1)
            want_grid = {b: self.torch_net.decode(tokens, cond, {b: centres})[b] for b in self.grid_branches}
            queries = torch.rand(1, 50, 3, generator=torch.Generator().manual_seed(1)).expand(batch, -1, -1)
            queries = queries.contiguous()
            want = {b: self.torch_net.decode(tokens, cond, {b: queries})[b] for b in self.branches}
        dynamic = {"query_pos": {1: "queries"}, "out": {1: "queries"}}
        if self.batch_axis:
            dynamic = {"tokens": {0: "batch"}, "query_pos": {0: "batch", 1: "queries"}, "cond": {0: "batch"},
                       "out": {0: "batch", 1: "queries"}}
        for b in self.branches:
            _export(_Decoder(self.torch_net, b), {"tokens": tokens[b], "query_pos": queries, "cond": cond},
                    ["out"], self.folder / f"{b}.onnx", dynamic)
        session = ort.InferenceSession(str(self.folder / "latents.onnx"), providers=["CPUExecutionProvider"])
        used = {i.name for i in session.get_inputs()}
        got = dict(zip(outputs, session.run(outputs, {k: v.numpy() for k, v in feed.items() if k in used}),
                       strict=True))
        worst = max(float(np.abs(got[b] - tokens[b].numpy()).max()) for b in self.branches)
        worst = max(worst, *(float(np.abs(got[f"grid_{b}"] - want_grid[b].numpy()).max())
                             for b in self.grid_branches))
        for b in self.branches:
            s = ort.InferenceSession(str(self.folder / f"{b}.onnx"), providers=["CPUExecutionProvider"])
            out = s.run(["out"], {"tokens": tokens[b].numpy(), "query_pos": queries.numpy(),
                                  "cond": cond.numpy()})[0]
            worst = max(worst, float(np.abs(out - want[b].numpy()).max()))
        if not worst <= EXPORT_TOLERANCE:
            raise DataError(f"{self.folder}: the exported net differs from the torch net by {worst:.2g} "
                            f"(> {EXPORT_TOLERANCE:g})", "use runtime=torch for this model")
        (self.folder / "checked.json").write_text(json.dumps({"max_abs_difference_to_torch": worst}) + "\n")
        log.info("exported the net to ONNX in %s (largest difference to torch %.2g)", self.folder, worst)

    def _grid_names(self) -> list[str]:
        return [f"grid_{b}" for b in self.grid_branches]

    # ---- the calls a rollout makes
    def latents(self, inputs: OperatorInputs, off_branches: bool = True) -> tuple[dict[str, torch.Tensor],
                                                                                 torch.Tensor]:
        if off_branches and not self.off_branches:
            raise ValueError("this export computes the main branches alone (off_branches=False)")
        grid_shape = tuple(int(n) for n in inputs.grid.shape[2:])
        if grid_shape != self.grid_shape:
            self.prepare(grid_shape)
        tensors = self._feed_tensors(inputs)
        feed = {k: tensors[k].detach().cpu().numpy() for k in self.latent_inputs}
        names = [*self.branches, "cond", *self._grid_names()]
        out = self.sessions["latents"].run(names, feed)
        tensors = {name: torch.from_numpy(a) for name, a in zip(names, out, strict=True)}
        cond = tensors.pop("cond")
        self._grid_out = {b: (tensors[b], tensors.pop(f"grid_{b}")) for b in self.grid_branches}
        return tensors, cond

    def decode(self, tokens: Mapping[str, torch.Tensor], cond: torch.Tensor,
               query_pos: Mapping[str, torch.Tensor], chunk_size: int | None = None) -> dict[str, torch.Tensor]:
        cond_np = cond.detach().cpu().numpy()
        out = {}
        for name, pos in query_pos.items():
            done = self._grid_out.get(name)
            if done is not None and done[0] is tokens[name] and self._at_centres(pos):
                out[name] = done[1]  # decoded by the latents call that made these tokens
                continue
            t = tokens[name].detach().cpu().numpy()
            chunks = [pos] if chunk_size is None else pos.split(chunk_size, dim=1)
            parts = [self.sessions[name].run(["out"], {"tokens": t, "query_pos": c.detach().cpu().numpy(),
                                                       "cond": cond_np})[0] for c in chunks]
            out[name] = torch.from_numpy(np.concatenate(parts, axis=1))
        return out

    def _at_centres(self, pos: torch.Tensor) -> bool:
        """Whether (B, Q, 3) query positions are the grid's cell centres, in their order, for every member."""
        return pos.shape[1:] == self._centres.shape and torch.equal(pos, self._centres.expand_as(pos))

