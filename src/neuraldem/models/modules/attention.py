"""Multi-head attention on already projected queries, keys and values (fused scaled_dot_product_attention).

Projections live in the blocks, because the multi-branch block projects each branch with its own weights and
then attends over the concatenation of several branches.
"""

from __future__ import annotations

import torch
from torch.nn import functional as F


def split_heads(x: torch.Tensor, num_heads: int) -> torch.Tensor:
    """(B, N, dim) -> (B, heads, N, dim / heads)."""
    batch, n, dim = x.shape
    return x.view(batch, n, num_heads, dim // num_heads).transpose(1, 2)


def merge_heads(x: torch.Tensor) -> torch.Tensor:
    """(B, heads, N, head_dim) -> (B, N, heads * head_dim)."""
    batch, heads, n, head_dim = x.shape
    return x.transpose(1, 2).reshape(batch, n, heads * head_dim)


def attend(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, num_heads: int) -> torch.Tensor:
    """Attention of queries (B, Nq, dim) over keys/values (B, Nk, dim) -> (B, Nq, dim); no mask."""
    out = F.scaled_dot_product_attention(split_heads(q, num_heads), split_heads(k, num_heads),
                                         split_heads(v, num_heads))
    return merge_heads(out)


def check_heads(dim: int, num_heads: int) -> None:
    """Heads must split the width evenly (a user's config is checked before, in `models.schemas`)."""
    if dim <= 0 or num_heads <= 0 or dim % num_heads:
        raise ValueError(f"attention width {dim} is not a positive multiple of {num_heads} heads")
