"""Train/val/test splits over the usable simulations of a manifest.

- random: shuffled with a seed into fractions (default 80/10/10).
- band: held-out parameter band (paper sec. 4.2 "Generalization"): every simulation with alpha inside
  the alpha band AND theta inside the theta band is test; val is a random fraction of the rest. With no
  theta band given, the theta band covers the same relative width of the observed theta range as the alpha
  band covers of the alpha range, centred on the observed theta range.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from neuraldem.data.manifest import SimRecord
from neuraldem.errors import DataError


def random_split(ids: Sequence[str], fractions: dict[str, float], seed: int) -> dict[str, list[str]]:
    ids = sorted(ids)
    rng = np.random.default_rng(seed)
    order = [ids[i] for i in rng.permutation(len(ids))]
    n = len(order)
    n_val = int(round(fractions.get("val", 0.0) * n))
    n_test = int(round(fractions.get("test", 0.0) * n))
    if n >= 3:  # a part that was asked for is never empty when the dataset allows it
        n_val = max(n_val, 1) if fractions.get("val", 0.0) > 0 else 0
        n_test = max(n_test, 1) if fractions.get("test", 0.0) > 0 else 0
    n_train = n - n_val - n_test
    return {"train": sorted(order[:n_train]), "val": sorted(order[n_train:n_train + n_val]),
            "test": sorted(order[n_train + n_val:])}


def auto_theta_band(thetas: np.ndarray, alpha_band: tuple[float, float],
                    alpha_range: tuple[float, float]) -> tuple[float, float]:
    rel = (alpha_band[1] - alpha_band[0]) / (alpha_range[1] - alpha_range[0])
    lo, hi = float(np.min(thetas)), float(np.max(thetas))
    centre, half = 0.5 * (lo + hi), 0.5 * rel * (hi - lo)
    return centre - half, centre + half


def band_split(records: Sequence[SimRecord], alpha_band: tuple[float, float],
               theta_band: tuple[float, float] | None, val_fraction: float, seed: int) -> dict[str, list[str]]:
    """Test = inside the (alpha, theta) band; the band's theta part is skipped when theta is unknown."""
    def inside(rec: SimRecord) -> bool:
        a = rec.params["alpha"]
        in_alpha = alpha_band[0] <= a <= alpha_band[1]
        if theta_band is None:
            return in_alpha
        theta = rec.macro.get("theta")
        if theta is None:
            raise DataError(f"simulation {rec.sim_id} has no theta: the band split needs characterization")
        return in_alpha and theta_band[0] <= theta <= theta_band[1]

    test = sorted(r.sim_id for r in records if inside(r))
    rest = [r.sim_id for r in records if not inside(r)]
    parts = random_split(rest, {"val": val_fraction, "test": 0.0}, seed)
    return {"train": parts["train"], "val": parts["val"], "test": test}
