"""The stochastic bed model: latent noise makes members differ (and is reproducible when given), and training
with the fair CRPS on two members recovers a spread an MSE fit averages away (toy Gaussian case, stated)."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from neuraldem.models.multi_branch_operator import MultiBranchOperator
from neuraldem.scenes.fluidized_bed.surrogate.module import fair_crps

SIGMA = 0.3
GRID = (6, 1, 15)


def _net(noise_dim: int) -> MultiBranchOperator:
    torch.manual_seed(0)
    return MultiBranchOperator(fluid_channels=1, mixing_channels=1, dim=16, num_heads=2, cond_dim=16,
                               encoder_depth=0, approximator_depth=1, decoder_depth=0, patch_size=(2, 1, 3),
                               mlp_ratio=2.0, particle_branch=False, noise_dim=noise_dim)


def _toy_batch(net: MultiBranchOperator, n: int, generator: torch.Generator):
    """Toy (synthetic, not solver data): every cell of a sample holds s + SIGMA * eps, one eps per sample."""
    x = net.example_inputs(n, grid_shape=GRID, generator=generator)
    s = x.scalars
    eps = torch.randn(n, 1, 1, generator=generator)
    target = (s[:, :, None] + SIGMA * eps).expand(n, math.prod(GRID), 1)
    return replace(x, query_pos={"fluid": x.query_pos["fluid"]}), target


def _train(net: MultiBranchOperator, members: int, steps: int = 150) -> None:
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    g = torch.Generator().manual_seed(1)
    for _ in range(steps):
        x, y = _toy_batch(net, 16, g)
        if members == 1:
            loss = (net(x)["fluid"] - y).square().mean()
        else:
            preds = torch.stack([net(x)["fluid"] for _ in range(members)])  # each call draws its own noise
            loss = fair_crps(preds, y)
        opt.zero_grad()
        loss.backward()
        opt.step()


def test_members_differ_and_given_noise_reproduces():
    net = _net(noise_dim=4).eval()
    with torch.no_grad():  # as after training: the zero-initialised modulation lets no conditioning through yet
        for p in net.parameters():
            p.add_(0.2 * torch.randn_like(p))
    x = net.example_inputs(2, grid_shape=GRID, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        a, b = net(x)["fluid"], net(x)["fluid"]
        z = torch.randn(2, 4)
        c, d = net(replace(x, noise=z))["fluid"], net(replace(x, noise=z))["fluid"]
    assert (a - b).abs().max() > 1e-4
    torch.testing.assert_close(c, d)
    with pytest.raises(ValueError, match="noise of shape"):
        net(replace(x, noise=torch.randn(2, 3)))


def test_fair_crps_known_values():
    y = torch.zeros(3)
    same = torch.ones(2, 3)  # two identical members at distance 1: CRPS = MAE = 1
    assert float(fair_crps(same, y)) == pytest.approx(1.0)
    spread = torch.tensor([[1.0], [-1.0]])  # members at +-1 around y: 1 - |2| / 2 = 0
    assert float(fair_crps(spread, torch.zeros(1))) == pytest.approx(0.0)


def test_crps_training_beats_the_deterministic_fit_on_a_gaussian_toy():
    stochastic, deterministic = _net(noise_dim=4), _net(noise_dim=0)
    _train(stochastic, members=2)
    _train(deterministic, members=1)
    g = torch.Generator().manual_seed(7)
    with torch.no_grad():
        x, y = _toy_batch(stochastic, 256, g)
        ens = torch.stack([stochastic(x)["fluid"] for _ in range(8)])
        crps_stochastic = float(fair_crps(ens, y))
        crps_deterministic = float(fair_crps(deterministic(x)["fluid"][None].expand(2, -1, -1, -1), y))
    # a perfect Gaussian forecast scores SIGMA / sqrt(pi) = 0.17; the exact mean alone SIGMA * sqrt(2 / pi) = 0.24
    assert crps_stochastic < 0.9 * crps_deterministic, (crps_stochastic, crps_deterministic)
    assert float(ens.std(dim=0).mean()) > 0.3 * SIGMA  # the members carry a real spread
