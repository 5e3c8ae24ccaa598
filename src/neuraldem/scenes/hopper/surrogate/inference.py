"""Hopper fields from the trained model in torch (`ModelPredictor`): what training, evaluation and benchmarks use.
The predictors that need no torch (the DEM data as a prediction, the model exported to ONNX) are in
`predictors.py`; all answer the same question, fields at fixed query points on a time grid."""

from __future__ import annotations

import numpy as np
import torch

from neuraldem.data.manifest import SimRecord
from neuraldem.data.normalization import HopperNormalizer
from neuraldem.scenes.hopper.surrogate.predictors import FieldQueries, TrajectoryFields


class ModelPredictor(FieldQueries):
    """A trained HopperFieldModel queried at every time of the grid (one batch of all times per chunk).
    `times_per_call`: times answered per forward call (more is faster, needs (times x Q x dim) memory)."""

    def __init__(self, net: torch.nn.Module, norm: HopperNormalizer, conditioning: list[str], chunk_size: int = 16384,
                 device: str = "cpu", times_per_call: int = 1, box_tolerance: float = 0.05):
        super().__init__(norm, conditioning, box_tolerance)
        self.net, self.chunk_size, self.device, self.times_per_call = net, chunk_size, device, times_per_call

    @torch.no_grad()
    def fields(self, rec: SimRecord, times: np.ndarray, points: np.ndarray) -> TrajectoryFields:
        self.net.eval()
        scalars = self.scalars(rec, times)
        q = torch.from_numpy(self._query_points(rec, points)).float().to(self.device)
        s = torch.from_numpy(scalars).to(self.device)
        occ, transport, residence = [], [], []
        n = self.times_per_call
        for k in range(0, len(times), n):  # one time per call (the default) keeps memory at (Q x dim)
            batch = s[k:k + n]
            out = self.net(batch, q[None].expand(len(batch), -1, -1), chunk_size=self.chunk_size)
            occ += list(torch.sigmoid(out["occupancy"][..., 0]).cpu().numpy())
            transport += list(out["transport"].cpu().numpy())
            residence += list(out["residence"][..., 0].cpu().numpy())
        return TrajectoryFields(times, np.stack(occ), self.norm.positions_back(np.stack(transport)),
                                self.norm.time_back(np.stack(residence)))
