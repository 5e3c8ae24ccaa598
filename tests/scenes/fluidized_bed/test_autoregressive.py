"""Re-sampling particles from a solid-fraction field: the density follows the field, nothing else."""

from __future__ import annotations

import torch

from neuraldem.scenes.fluidized_bed.autoregressive import sample_positions


def _cells(pos: torch.Tensor, shape: tuple[int, int, int]) -> torch.Tensor:
    ijk = (pos * torch.tensor(shape)).floor().long()
    return (ijk[..., 0] * shape[1] + ijk[..., 1]) * shape[2] + ijk[..., 2]


def test_samples_fall_where_the_solid_is_in_proportion():
    shape = (4, 1, 5)
    alpha = torch.zeros(2, *shape)
    alpha[0, 1, 0, 2] = 0.5  # sample 0: one cell
    alpha[1, 0, 0, 0], alpha[1, 3, 0, 4] = 0.1, 0.3  # sample 1: two cells, 1 : 3
    alpha[1, 2, 0, 1] = -0.2  # negative = empty
    g = torch.Generator().manual_seed(0)
    pos = sample_positions(alpha, 20000, g)
    assert pos.shape == (2, 20000, 3) and pos.min() >= 0 and pos.max() < 1
    cells = _cells(pos, shape)
    assert torch.all(cells[0] == 1 * 5 + 2)
    counts = torch.bincount(cells[1], minlength=20)
    assert counts.sum() == counts[0] + counts[3 * 5 + 4]
    assert 0.72 < counts[19] / 20000 < 0.78
    # uniform inside the cell
    inside = pos[0] * torch.tensor(shape) - torch.tensor([1.0, 0.0, 2.0])
    assert torch.allclose(inside.mean(0), torch.full((3,), 0.5), atol=0.02)


def test_empty_or_non_finite_fields_do_not_crash():
    alpha = torch.full((1, 2, 1, 2), float("nan"))
    alpha[0, 1, 0, 1] = 0.4
    cells = _cells(sample_positions(alpha, 500, torch.Generator().manual_seed(1)), (2, 1, 2))
    assert torch.all(cells == 3)
    pos = sample_positions(torch.zeros(1, 2, 1, 2), 400, torch.Generator().manual_seed(1))  # no solid: uniform
    assert len(torch.unique(_cells(pos, (2, 1, 2)))) == 4
