"""A particle-based learned simulator (GNS-style graph network): the particle-based baseline of the benchmarks.

The idea of Sanchez-Gonzalez et al. (2020), "Learning to simulate complex physics with graph networks": every
particle is a node of a graph whose edges join particles closer than a connectivity radius. Encode-process-
decode: MLPs embed the node inputs (a short history of normalised velocities, the distances to the domain's
walls clipped at the radius, scene-specific boundary features and the run's conditioning scalars) and the
edge inputs (relative displacement and distance, in radii); M message-passing steps update edges and nodes
with residual connections; an MLP decodes every node's (normalised) acceleration.

No absolute position enters the net, only differences (edges) and distances to walls, so shifting the
particles and the walls together leaves the prediction unchanged; sum aggregation makes it equivariant to a
permutation of the particles (as long as no node has more than `max_neighbours` neighbours within the radius,
where `torch_cluster.radius_graph` keeps an order-dependent subset).

forward(pos (N, 3), velocities (N, H, 3), box_lo (B, 3), box_hi (B, 3), batch (N,), scalars (B, S),
wall_distance (N, E) | None) -> (N, 3). `wall_distance`: distances to E further walls of the scene (e.g. a hopper's
cone and cylinder), clipped here like the box walls. Positions and box in one length unit (the data layer uses particle
diameters), `radius` in that unit; velocities and the output in model units (standardised by the data layer).
"""

from __future__ import annotations

import torch
from torch import nn
from torch_cluster import radius_graph
from torch_geometric.nn import MessagePassing

N_BOX_WALLS = 6  # distance to the lower and upper wall of the box along x, y, z


def mlp(in_dim: int, hidden: int, out_dim: int, layers: int, norm: bool = True) -> nn.Sequential:
    """`layers` hidden layers of width `hidden` with ReLU, then a linear output (+ LayerNorm)."""
    mods: list[nn.Module] = []
    d = in_dim
    for _ in range(layers):
        mods += [nn.Linear(d, hidden), nn.ReLU()]
        d = hidden
    mods.append(nn.Linear(d, out_dim))
    if norm:
        mods.append(nn.LayerNorm(out_dim))
    return nn.Sequential(*mods)


def wall_distances(pos: torch.Tensor, box_lo: torch.Tensor, box_hi: torch.Tensor, batch: torch.Tensor,
                   radius: float) -> torch.Tensor:
    """(N, 6) distances to the box's lower and upper walls per axis, in radii, clipped to [-1, 1] (a particle
    further than the radius from a wall does not see it; negative = outside the box)."""
    lower = pos - box_lo[batch]
    upper = box_hi[batch] - pos
    return (torch.cat([lower, upper], dim=-1) / radius).clamp(-1.0, 1.0)


class InteractionStep(MessagePassing):
    """One message-passing step: edge update from (edge, receiver, sender), sum of incoming edges per node,
    node update from (node, aggregated edges); both with residual connections."""

    def __init__(self, dim: int, hidden: int, layers: int):
        super().__init__(aggr="add")
        self.edge_mlp = mlp(3 * dim, hidden, dim, layers)
        self.node_mlp = mlp(2 * dim, hidden, dim, layers)

    def forward(self, h: torch.Tensor, e: torch.Tensor, edge_index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        src, dst = edge_index
        e_new = self.edge_mlp(torch.cat([e, h[dst], h[src]], dim=-1))
        incoming = self.propagate(edge_index, message_in=e_new, size=(h.shape[0], h.shape[0]))
        h_new = self.node_mlp(torch.cat([h, incoming], dim=-1))
        return h + h_new, e + e_new

    def message(self, message_in: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        return message_in


class GraphNetworkSimulator(nn.Module):
    """Encode-process-decode graph network predicting per-particle accelerations (module docstring).

    Args:
        n_scalars: conditioning scalars per graph (set by the LightningModule from the data).
        history: velocities in the input history H (the data layer reads H + 1 past positions).
        n_extra_walls: scene walls E beyond the box (e.g. a hopper's cone and cylinder), as distances.
        radius: connectivity radius (the data's length unit); max_neighbours: cap per node (torch_cluster).
        dim: latent width; hidden: MLP hidden width; mlp_layers: hidden layers per MLP; steps: M.
    """

    def __init__(self, n_scalars: int, history: int = 5, n_extra_walls: int = 0, radius: float = 2.0,
                 max_neighbours: int = 64, dim: int = 64, hidden: int = 64, mlp_layers: int = 2,
                 steps: int = 5) -> None:
        super().__init__()
        self.n_scalars, self.history, self.n_extra_walls = n_scalars, history, n_extra_walls
        self.radius, self.max_neighbours, self.steps = float(radius), max_neighbours, steps
        node_in = 3 * history + N_BOX_WALLS + n_extra_walls + n_scalars
        self.node_encoder = mlp(node_in, hidden, dim, mlp_layers)
        self.edge_encoder = mlp(4, hidden, dim, mlp_layers)  # relative displacement (3) + distance, in radii
        self.processor = nn.ModuleList(InteractionStep(dim, hidden, mlp_layers) for _ in range(steps))
        self.decoder = mlp(dim, hidden, 3, mlp_layers, norm=False)

    def graph(self, pos: torch.Tensor, batch: torch.Tensor) -> torch.Tensor:
        """(2, E) edges (sender, receiver) between particles of the same graph closer than the radius."""
        return radius_graph(pos, r=self.radius, batch=batch, loop=False, max_num_neighbors=self.max_neighbours)

    def node_inputs(self, pos: torch.Tensor, velocities: torch.Tensor, box_lo: torch.Tensor, box_hi: torch.Tensor,
                    batch: torch.Tensor, scalars: torch.Tensor, wall_distance: torch.Tensor | None) -> torch.Tensor:
        n = pos.shape[0]
        if velocities.shape != (n, self.history, 3):
            raise ValueError(f"velocities have shape {tuple(velocities.shape)}, expected ({n}, {self.history}, 3)")
        parts = [velocities.reshape(n, 3 * self.history), wall_distances(pos, box_lo, box_hi, batch, self.radius)]
        if self.n_extra_walls:
            if wall_distance is None or wall_distance.shape != (n, self.n_extra_walls):
                got = None if wall_distance is None else tuple(wall_distance.shape)
                raise ValueError(f"wall_distance has shape {got}, expected ({n}, {self.n_extra_walls})")
            parts.append((wall_distance / self.radius).clamp(-1.0, 1.0))
        if self.n_scalars:
            parts.append(scalars[batch])
        return torch.cat(parts, dim=-1)

    def forward(self, pos: torch.Tensor, velocities: torch.Tensor, box_lo: torch.Tensor, box_hi: torch.Tensor,
                batch: torch.Tensor, scalars: torch.Tensor, wall_distance: torch.Tensor | None = None) -> torch.Tensor:
        edge_index = self.graph(pos, batch)
        src, dst = edge_index
        rel = (pos[src] - pos[dst]) / self.radius
        h = self.node_encoder(self.node_inputs(pos, velocities, box_lo, box_hi, batch, scalars, wall_distance))
        e = self.edge_encoder(torch.cat([rel, rel.norm(dim=-1, keepdim=True)], dim=-1))
        for step in self.processor:
            h, e = step(h, e, edge_index)
        return self.decoder(h)

    def example_inputs(self, n_graphs: int = 2, n_particles: int = 50, box: float = 8.0,
                       generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
        """Random inputs of the right shapes (smoke tests, benchmarks): kwargs for `forward`."""
        device = self.decoder[0].weight.device
        n = n_graphs * n_particles
        out = {
            "pos": box * torch.rand(n, 3, generator=generator),
            "velocities": torch.randn(n, self.history, 3, generator=generator),
            "box_lo": torch.zeros(n_graphs, 3),
            "box_hi": torch.full((n_graphs, 3), box),
            "batch": torch.arange(n_graphs).repeat_interleave(n_particles),
            "scalars": torch.rand(n_graphs, self.n_scalars, generator=generator),
            "wall_distance": (box * torch.rand(n, self.n_extra_walls, generator=generator)
                              if self.n_extra_walls else None),
        }
        return {k: (v.to(device) if v is not None else None) for k, v in out.items()}
