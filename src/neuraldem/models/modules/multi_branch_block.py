"""Multi-branch transformer block: tightly coupled main branches plus read-only off-branches.

Every branch has its own weights (projections, MLP, DiT modulation); nothing is shared between branches.

* Main branches attend jointly (MMDiT-style): the queries, keys and values of all main branches are
  concatenated along the token axis, attended together and split back per branch.
* Off-branches use their own tokens as queries and attend over [main tokens, own tokens]. The main tokens are
  detached and so is the conditioning vector, so an off-branch can neither change a main-branch output nor
  send a gradient into anything a main branch uses (the shared scalar conditioner included).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import nn

from neuraldem.models.modules.attention import attend, check_heads
from neuraldem.models.modules.dit_modulation import DitModulation, dit_norm, modulate
from neuraldem.models.modules.mlp import Mlp


class _BranchLayers(nn.Module):
    """What every branch owns besides its attention projections: norms, output projection, MLP, modulation."""

    def __init__(self, dim: int, cond_dim: int, mlp_ratio: float) -> None:
        super().__init__()
        self.attn_norm = dit_norm(dim)
        self.attn_out = nn.Linear(dim, dim)
        self.mlp_norm = dit_norm(dim)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))
        self.modulation = DitModulation(dim, cond_dim, n_vectors=6)

    def mlp_residual(self, x: torch.Tensor, shift: torch.Tensor, scale: torch.Tensor,
                     gate: torch.Tensor) -> torch.Tensor:
        return x + gate * self.mlp(modulate(self.mlp_norm(x), shift, scale))


class MainBranchLayers(_BranchLayers):
    def __init__(self, dim: int, cond_dim: int, mlp_ratio: float) -> None:
        super().__init__(dim, cond_dim, mlp_ratio)
        self.qkv = nn.Linear(dim, 3 * dim)


class OffBranchLayers(_BranchLayers):
    """Queries come from the branch's own tokens only; keys/values from [main tokens, own tokens]."""

    def __init__(self, dim: int, cond_dim: int, mlp_ratio: float) -> None:
        super().__init__(dim, cond_dim, mlp_ratio)
        self.q = nn.Linear(dim, dim)
        self.kv = nn.Linear(dim, 2 * dim)


def check_branches(main_branches: Sequence[str], off_branches: Sequence[str]) -> tuple[list[str], list[str]]:
    main, off = [str(b) for b in main_branches], [str(b) for b in off_branches]
    if not main or len(set(main + off)) != len(main + off):
        raise ValueError(f"main branches {main} and off-branches {off} must be non-empty and distinct; "
                         "each branch must be one or the other")
    return main, off


class MultiBranchTransformerBlock(nn.Module):
    """tokens {branch: (B, N_branch, dim)}, cond (B, cond_dim) -> tokens of the same shapes."""

    def __init__(self, dim: int, num_heads: int, cond_dim: int, main_branches: Sequence[str],
                 off_branches: Sequence[str] = (), mlp_ratio: float = 4.0) -> None:
        super().__init__()
        check_heads(dim, num_heads)
        self.main_branches, self.off_branches = check_branches(main_branches, off_branches)
        self.num_heads = num_heads
        self.main = nn.ModuleDict({name: MainBranchLayers(dim, cond_dim, mlp_ratio)
                                   for name in self.main_branches})
        self.off = nn.ModuleDict({name: OffBranchLayers(dim, cond_dim, mlp_ratio)
                                  for name in self.off_branches})

    def forward(self, tokens: Mapping[str, torch.Tensor], cond: torch.Tensor,
                off_branches: bool = True) -> dict[str, torch.Tensor]:
        """off_branches=False: the main branches alone (their outputs never depend on an off-branch)."""
        off = self.off_branches if off_branches else []
        missing = [b for b in self.main_branches + off if b not in tokens]
        if missing:
            raise ValueError(f"tokens for branches {missing} are missing (got {sorted(tokens)})")
        out = self._main_forward(tokens, cond)
        context = [tokens[name].detach() for name in self.main_branches]
        for name in off:
            out[name] = self._off_forward(self.off[name], tokens[name], context, cond.detach())
        return out

    def _main_forward(self, tokens: Mapping[str, torch.Tensor],
                      cond: torch.Tensor) -> dict[str, torch.Tensor]:
        mods = {name: self.main[name].modulation(cond) for name in self.main_branches}
        qkv = [
            self.main[name].qkv(modulate(self.main[name].attn_norm(tokens[name]), *mods[name][:2]))
            for name in self.main_branches
        ]
        q, k, v = torch.cat(qkv, dim=1).chunk(3, dim=-1)
        attended = attend(q, k, v, self.num_heads).split([t.shape[1] for t in qkv], dim=1)
        out = {}
        for name, branch_attended in zip(self.main_branches, attended, strict=True):
            layers = self.main[name]
            _, _, attn_gate, mlp_shift, mlp_scale, mlp_gate = mods[name]
            x = tokens[name] + attn_gate * layers.attn_out(branch_attended)
            out[name] = layers.mlp_residual(x, mlp_shift, mlp_scale, mlp_gate)
        return out

    def _off_forward(self, layers: OffBranchLayers, x: torch.Tensor, main_context: list[torch.Tensor],
                     cond: torch.Tensor) -> torch.Tensor:
        attn_shift, attn_scale, attn_gate, mlp_shift, mlp_scale, mlp_gate = layers.modulation(cond)
        context = modulate(layers.attn_norm(torch.cat([*main_context, x], dim=1)), attn_shift, attn_scale)
        own = context[:, -x.shape[1]:]
        k, v = layers.kv(context).chunk(2, dim=-1)
        x = x + attn_gate * layers.attn_out(attend(layers.q(own), k, v, self.num_heads))
        return layers.mlp_residual(x, mlp_shift, mlp_scale, mlp_gate)
