"""UPT-style supernode pooling: encodes an arbitrary particle cloud into a fixed number of tokens.

Supernodes are a subset of the input particles. Each supernode receives a message from every particle within
`radius` (at most `max_neighbours` of them) and averages them, so a token summarises its neighbourhood
independently of how many particles discretise it and of their order.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import torch
from torch import nn
from torch_cluster import radius as radius_graph

from neuraldem.errors import ConfigError
from neuraldem.models.modules.mlp import Mlp
from neuraldem.models.modules.position_embedding import ContinuousSincosEmbed

POSITION_MODES = ("relative", "absolute", "both")
EVAL_SEED = 0  # fixed supernode choice at inference, so evaluating a state twice gives the same prediction


def select_supernodes(batch_size: int, n_particles: int, n_supernodes: int, *, device: torch.device,
                      generator: torch.Generator | None = None,
                      key: str = "model.net.n_supernodes") -> torch.Tensor:
    """A uniformly random subset of particle indices per sample, (B, n_supernodes), without repeats."""
    if n_supernodes > n_particles:
        raise ConfigError(f"config value {key}={n_supernodes} is invalid: a sample has only {n_particles} "
                          f"particles (override it, e.g. {key}={n_particles})")
    # a seeded generator lives on the CPU; without one, draw directly on the particles' device
    noise = torch.rand(batch_size, n_particles, generator=generator,
                       device=generator.device if generator is not None else device)
    return noise.topk(n_supernodes, dim=1).indices.to(device)


@lru_cache(maxsize=16)
@torch.inference_mode(False)  # a plain tensor even when first asked for in a rollout step: training reuses it
def _eval_supernodes(batch_size: int, n_particles: int, n_supernodes: int, device: torch.device) -> torch.Tensor:
    """The supernodes of eval mode (drawn with `EVAL_SEED`): the same for every state of a shape, so drawn once
    per shape (a rollout step asked for them every step)."""
    generator = torch.Generator().manual_seed(EVAL_SEED)
    return select_supernodes(batch_size, n_particles, n_supernodes, device=device, generator=generator,
                             key="model.net.n_supernodes_eval")


@dataclass(frozen=True)
class ParticleGraph:
    """Which particles each supernode pools, for one batch of positions: the supernodes (B, M) (indices into
    the N particles) and the edges (2, E), row 0 the flat supernode index (b * M + m), row 1 the flat particle
    index (b * N + n). Computed once, it can be reused by a caller that holds the same positions (a rollout
    that also needs to know which particles the encoder will read)."""

    supernode_idx: torch.Tensor
    edges: torch.Tensor

    def particles_read(self) -> torch.Tensor:
        """Sorted flat indices of the particles whose features the encoder reads (the others it never sees)."""
        return torch.unique(self.edges[1])


class SupernodePooling(nn.Module):
    """Particles (B, N, ndim) positions + (B, N, C) features -> (B, n_supernodes, dim) tokens.

    Positions are normalised to [0, 1] per axis (the domain box), like every coordinate in neuraldem, and
    `radius` is in those units. A message is MLP([features, embedding of the particle position relative to
    the supernode and/or of its absolute position, per `position_mode`]); a token is the mean of its messages.
    Supernodes: `supernode_idx` (B, M) when given; otherwise `n_supernodes` random particles in training and
    `n_supernodes_eval` particles chosen with a fixed seed in eval mode.
    If a supernode has more than `max_neighbours` particles in range, torch_cluster keeps only some of them;
    choose the radius so this is rare (it makes the token depend on the particle order).
    """

    def __init__(self, in_channels: int, dim: int, radius: float, n_supernodes: int,
                 n_supernodes_eval: int | None = None, max_neighbours: int = 32, ndim: int = 3,
                 position_mode: str = "both") -> None:
        super().__init__()
        if position_mode not in POSITION_MODES:
            raise ValueError(f"position_mode {position_mode!r} is not one of {POSITION_MODES}")
        self.in_channels = in_channels
        self.radius = float(radius)
        self.n_supernodes = n_supernodes
        self.n_supernodes_eval = n_supernodes if n_supernodes_eval is None else n_supernodes_eval
        self.max_neighbours = max_neighbours
        self.position_mode = position_mode
        self.pos_embed = ContinuousSincosEmbed(dim, ndim)
        n_embeddings = 2 if position_mode == "both" else 1
        self.message = Mlp(in_channels + n_embeddings * dim, dim, dim)

    def choose_supernodes(self, positions: torch.Tensor) -> torch.Tensor:
        batch_size, n_particles, _ = positions.shape
        if self.training:
            return select_supernodes(batch_size, n_particles, self.n_supernodes, device=positions.device)
        return _eval_supernodes(batch_size, n_particles, self.n_supernodes_eval, positions.device).clone()

    def graph(self, positions: torch.Tensor, supernode_idx: torch.Tensor | None = None) -> ParticleGraph:
        """The supernodes (`supernode_idx`, else `choose_supernodes`) and the particles each one pools."""
        batch_size, n_particles, ndim = positions.shape
        if supernode_idx is None:
            supernode_idx = self.choose_supernodes(positions)
        n_supernodes = supernode_idx.shape[1]
        supernode_pos = torch.gather(positions, 1, supernode_idx.unsqueeze(-1).expand(-1, -1, ndim))
        batch_x = batch_y = None  # one sample: no batch vectors (the same edges, checked on random clouds)
        if batch_size > 1:
            batch = torch.arange(batch_size, device=positions.device)
            batch_x, batch_y = batch.repeat_interleave(n_particles), batch.repeat_interleave(n_supernodes)
        edges = radius_graph(positions.reshape(-1, ndim), supernode_pos.reshape(-1, ndim), self.radius,
                             batch_x=batch_x, batch_y=batch_y, max_num_neighbors=self.max_neighbours)
        return ParticleGraph(supernode_idx, edges)

    def messages(self, positions: torch.Tensor, features: torch.Tensor, graph: ParticleGraph) -> torch.Tensor:
        """(E, dim): the message along each edge of `graph`, before the mean per supernode (which an ONNX export
        takes in another form, `models.operator_onnx`)."""
        ndim = positions.shape[-1]
        supernode_pos = torch.gather(positions, 1, graph.supernode_idx.unsqueeze(-1).expand(-1, -1, ndim))
        flat_pos = positions.reshape(-1, ndim)
        flat_supernode_pos = supernode_pos.reshape(-1, ndim)
        supernode, particle = graph.edges[0], graph.edges[1]
        message_inputs = [features.reshape(-1, self.in_channels)[particle]]
        if self.position_mode in ("relative", "both"):
            message_inputs.append(self.pos_embed(flat_pos[particle] - flat_supernode_pos[supernode]))
        if self.position_mode in ("absolute", "both"):
            message_inputs.append(self.pos_embed(flat_pos[particle]))
        return self.message(torch.cat(message_inputs, dim=-1))

    def forward(self, positions: torch.Tensor, features: torch.Tensor,
                supernode_idx: torch.Tensor | None = None, graph: ParticleGraph | None = None) -> torch.Tensor:
        """`graph`: the particle graph of these very positions (`graph(positions)`), when the caller has it."""
        batch_size, n_particles, _ = positions.shape
        if features.shape[:2] != positions.shape[:2] or features.shape[2] != self.in_channels:
            raise ValueError(f"expected particle features of shape ({batch_size}, {n_particles}, "
                             f"{self.in_channels}), got {tuple(features.shape)}")
        if graph is None:
            graph = self.graph(positions, supernode_idx)
        messages = self.messages(positions, features, graph)
        n_supernodes = graph.supernode_idx.shape[1]
        n_tokens = batch_size * n_supernodes
        supernode = graph.edges[0]
        summed = messages.new_zeros(n_tokens, messages.shape[-1]).index_add_(0, supernode, messages)
        counts = torch.bincount(supernode, minlength=n_tokens).clamp(min=1).unsqueeze(-1)
        return (summed / counts).view(batch_size, n_supernodes, -1)
