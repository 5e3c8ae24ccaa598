"""Multi-branch neural operator for coupled particle-fluid systems (fluidized bed), for next-step prediction.

encoder (supernode pooling for particles, patch embedding for grids) -> multi-branch transformer blocks
(encoder, approximator and decoder stages) -> one perceiver decoder per branch. Main branches "particles" and
"fluid" are coupled in every block; the off-branch "mixing" reads from them but never influences them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import torch
from torch import nn

from neuraldem.models.modules.mlp import Mlp
from neuraldem.models.modules.multi_branch_block import MultiBranchTransformerBlock
from neuraldem.models.modules.patch_embedding import PatchEmbedding, cell_centres
from neuraldem.models.modules.perceiver_decoder import PerceiverDecoder
from neuraldem.models.modules.position_embedding import DEFAULT_COORD_SCALE
from neuraldem.models.modules.scalar_conditioner import ScalarConditioner
from neuraldem.models.modules.supernode_pooling import ParticleGraph, SupernodePooling

MAIN_BRANCHES = ("particles", "fluid")
OFF_BRANCHES = ("mixing",)
BRANCHES = MAIN_BRANCHES + OFF_BRANCHES


@dataclass
class OperatorInputs:
    """One batch of model inputs; every coordinate is normalised to [0, 1] per axis of the domain box.

    particle_pos (B, N, 3) and particle_features (B, N, Cp) (e.g. the last displacement);
    grid (B, Cg, X, Y, Z): fluid-branch cells (e.g. fluid velocity + solid fraction), covering the domain box;
    mixing_grid (B, Cm, X', Y', Z'): off-branch cells (e.g. mixing concentration), same convention;
    scalars (B, S): normalised conditioning scalars (e.g. inlet velocity);
    query_pos {branch: (B, Q_branch, 3)}: where to decode each branch (branches left out are not decoded);
    supernode_idx (B, M): optional explicit supernodes (indices into the N particles);
    particle_graph: optional, the particle encoder's graph of exactly these positions (`SupernodePooling.graph`),
    so a caller that needed it already does not compute it twice (whoever changes the positions drops it);
    noise (B, noise_dim): the latent noise of a stochastic net (drawn from the global generator when None).
    """

    particle_pos: torch.Tensor
    particle_features: torch.Tensor
    grid: torch.Tensor
    mixing_grid: torch.Tensor
    scalars: torch.Tensor
    query_pos: Mapping[str, torch.Tensor] = field(default_factory=dict)
    supernode_idx: torch.Tensor | None = None
    particle_graph: ParticleGraph | None = None
    noise: torch.Tensor | None = None


class MultiBranchOperator(nn.Module):
    """Maps the state at time t to the fields at t + dt, for the branches particles, fluid and mixing.

    Args:
        n_scalars: conditioning scalars S. particle_channels / fluid_channels / mixing_channels: input
        channels of each branch, also its output channels (next-step prediction of the same quantities).
        dim, num_heads, cond_dim, mlp_ratio: transformer width, heads, conditioning width, MLP ratio.
        encoder_depth, approximator_depth, decoder_depth: multi-branch blocks per stage (paper: 4 each).
        n_supernodes, n_supernodes_eval, radius, max_neighbours, position_mode: particle encoder
        (see `SupernodePooling`; radius in normalised units). patch_size: cells per patch along (X, Y, Z).
        particle_branch: False drops the particle branch (no supernode pooling, no particle decoder): a
        grid-only model whose main branch is the fluid grid, the "single branch" ablation of right-sizing.
        noise_dim: > 0 makes the net stochastic: a Gaussian noise vector of this size, embedded by an MLP, is
        added to the conditioning vector (so it reaches every block through the DiT modulation); members of an
        ensemble differ only in their noise (trained with CRPS, `neuraldem.scenes.fluidized_bed.surrogate.options`).
        scalar_coord_scale: sin-cos scale of the scalars (normalised to [0, 1]); the default is the positions'
        1000, with which the embedding turns by ~2 rad per 0.002 of the range, so a net may answer one unseen
        velocity unlike its neighbours (a bed net that collapsed at exactly 2.050 m/s and at no velocity
        0.002 m/s either side, results/fluidized_bed/options/velocity_embedding_scale1000_scan.png); a small
        scale (e.g. 10, the hopper's) keeps nearby scalars nearby.

    forward(inputs: OperatorInputs, chunk_size=None) -> {branch: (B, Q_branch, channels)} for the branches in
    `inputs.query_pos`.
    """

    def __init__(self, n_scalars: int = 1, particle_channels: int = 3, fluid_channels: int = 4,
                 mixing_channels: int = 1, dim: int = 192, num_heads: int = 3, cond_dim: int = 384,
                 encoder_depth: int = 1, approximator_depth: int = 1, decoder_depth: int = 1,
                 n_supernodes: int = 256, n_supernodes_eval: int | None = None, radius: float = 0.05,
                 max_neighbours: int = 32, position_mode: str = "both",
                 patch_size: Sequence[int] = (2, 1, 2), mlp_ratio: float = 4.0, particle_branch: bool = True,
                 noise_dim: int = 0, scalar_coord_scale: float = DEFAULT_COORD_SCALE) -> None:
        super().__init__()
        self.noise_dim, self.n_scalars, self.particle_branch = noise_dim, n_scalars, bool(particle_branch)
        self.main_branches = MAIN_BRANCHES if self.particle_branch else ("fluid",)
        self.branches = self.main_branches + OFF_BRANCHES
        self.channels = {"particles": particle_channels, "fluid": fluid_channels, "mixing": mixing_channels}
        self.conditioner = ScalarConditioner(n_scalars, dim, cond_dim, coord_scales=scalar_coord_scale)
        self.noise_embed = Mlp(noise_dim, cond_dim, cond_dim) if noise_dim else None
        self.encoders = nn.ModuleDict()
        if self.particle_branch:
            self.encoders["particles"] = SupernodePooling(particle_channels, dim, radius, n_supernodes,
                                                          n_supernodes_eval, max_neighbours, ndim=3,
                                                          position_mode=position_mode)
        self.encoders["fluid"] = PatchEmbedding(fluid_channels, dim, patch_size)
        self.encoders["mixing"] = PatchEmbedding(mixing_channels, dim, patch_size)

        def stage(depth: int) -> nn.ModuleList:
            return nn.ModuleList(
                MultiBranchTransformerBlock(dim, num_heads, cond_dim, self.main_branches, OFF_BRANCHES, mlp_ratio)
                for _ in range(depth))

        self.encoder_blocks = stage(encoder_depth)
        self.approximator_blocks = stage(approximator_depth)
        self.decoder_blocks = stage(decoder_depth)
        self.decoders = nn.ModuleDict({
            name: PerceiverDecoder(dim, self.channels[name], num_heads, cond_dim, ndim=3, mlp_ratio=mlp_ratio)
            for name in self.branches
        })

    def encode(self, inputs: OperatorInputs, off_branches: bool = True) -> dict[str, torch.Tensor]:
        """Input fields -> tokens {branch: (B, n_tokens_branch, dim)} (the main branches' alone without
        `off_branches`)."""
        tokens = {}
        if self.particle_branch:
            tokens["particles"] = self.encoders["particles"](inputs.particle_pos, inputs.particle_features,
                                                             inputs.supernode_idx, inputs.particle_graph)
        tokens["fluid"] = self.encoders["fluid"](inputs.grid)
        if off_branches:
            tokens["mixing"] = self.encoders["mixing"](inputs.mixing_grid)
        return tokens

    def forward(self, inputs: OperatorInputs, chunk_size: int | None = None) -> dict[str, torch.Tensor]:
        tokens, cond = self.latents(inputs)
        return self.decode(tokens, cond, inputs.query_pos, chunk_size=chunk_size)

    def latents(self, inputs: OperatorInputs,
                off_branches: bool = True) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        """Tokens after the last block and the conditioning vector: decode them once or in several calls
        (a rollout decodes the grid first, then the particles at positions sampled from the new grid).
        off_branches=False computes the main branches alone, for a caller that decodes no off-branch: they
        are the same either way (an off-branch only reads the main tokens)."""
        cond = self.conditioner(inputs.scalars)
        if self.noise_embed is not None:
            z = inputs.noise
            if z is None:
                z = torch.randn(cond.shape[0], self.noise_dim, device=cond.device, dtype=cond.dtype)
            if z.shape != (cond.shape[0], self.noise_dim):
                raise ValueError(f"noise of shape {tuple(z.shape)}; expected ({cond.shape[0]}, {self.noise_dim})")
            cond = cond + self.noise_embed(z)
        tokens = self.encode(inputs, off_branches)
        for block in [*self.encoder_blocks, *self.approximator_blocks, *self.decoder_blocks]:
            tokens = block(tokens, cond, off_branches)
        return tokens, cond

    def decode(self, tokens: Mapping[str, torch.Tensor], cond: torch.Tensor,
               query_pos: Mapping[str, torch.Tensor], chunk_size: int | None = None) -> dict[str, torch.Tensor]:
        """{branch: (B, Q_branch, channels)} at `query_pos` from the output of `latents`."""
        unknown = sorted(set(query_pos) - set(self.branches))
        if unknown:
            raise ValueError(f"query positions for unknown branches {unknown}; branches are {list(self.branches)}")
        # off-branch decoders see a detached conditioning vector, like the off-branches inside the blocks
        return {
            name: self.decoders[name](tokens[name], pos, cond if name in MAIN_BRANCHES else cond.detach(),
                                      chunk_size=chunk_size)
            for name, pos in query_pos.items()
        }

    def example_inputs(self, batch_size: int = 2, n_particles: int | None = None,
                       grid_shape: Sequence[int] = (12, 1, 30),
                       generator: torch.Generator | None = None) -> OperatorInputs:
        """Random inputs of the right shapes (smoke tests, benchmarks), decoded at particles and cells."""
        device = self.conditioner.merge.weight.device
        if n_particles is None:
            pooling = self.encoders["particles"] if self.particle_branch else None
            n_particles = 2 * max(pooling.n_supernodes, pooling.n_supernodes_eval) if pooling else 64

        def rand(*shape: int) -> torch.Tensor:
            return torch.rand(*shape, generator=generator).to(device)

        particle_pos = rand(batch_size, n_particles, 3)
        centres = cell_centres(grid_shape, device=device).expand(batch_size, -1, -1)
        return OperatorInputs(
            particle_pos=particle_pos,
            particle_features=rand(batch_size, n_particles, self.channels["particles"]),
            grid=rand(batch_size, self.channels["fluid"], *grid_shape),
            mixing_grid=rand(batch_size, self.channels["mixing"], *grid_shape),
            scalars=rand(batch_size, self.n_scalars),
            query_pos=(({"particles": particle_pos} if self.particle_branch else {})
                       | {"fluid": centres, "mixing": centres}),
        )
