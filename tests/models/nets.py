"""Helpers for the model tests: waking up fresh DiT blocks and short training loops."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

from neuraldem.models.modules.dit_modulation import DitModulation


def activate_modulations(model: nn.Module, std: float = 0.1, seed: int = 0) -> nn.Module:
    """Give every DiT modulation random weights, so no block is the identity any more.

    Fresh blocks are the identity (zero gates); without this, tests of attention properties pass trivially.
    """
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for module in model.modules():
            if isinstance(module, DitModulation):
                for param in module.proj.parameters():
                    param.copy_(torch.randn(param.shape, generator=generator) * std)
    return model


def fit(model: nn.Module, loss_fn: Callable[[], torch.Tensor], steps: int, lr: float = 1e-3) -> list[float]:
    """`steps` Adam updates on `loss_fn()`; returns the loss before each update."""
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    losses = []
    for _ in range(steps):
        optimizer.zero_grad()
        loss = loss_fn()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    return losses
