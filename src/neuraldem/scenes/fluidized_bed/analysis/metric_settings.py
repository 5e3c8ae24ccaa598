"""How the bed's answers are read from its fields (`analysis.metrics`): the settings a dataset, a released model and
a what-if share. Apart from `dataset.datagen` (which imports the solver driver and scipy.stats, ~0.5 s) so
that a what-if reads them cheaply."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from omegaconf import OmegaConf

from neuraldem.config import checks
from neuraldem.errors import ConfigError


@dataclass
class BedMetricSettings:
    lacey_block: tuple[int, int, int] = (2, 1, 2)  # sample cell = this many grid cells per axis
    lacey_min_count: float = 5.0  # sample cells with fewer particles are skipped
    bed_quantile: float = 0.95
    bubble_threshold: float = 0.15  # solid fraction below which a bed cell is a void

    @classmethod
    def from_config(cls, cfg: Any, key: str) -> BedMetricSettings:
        s = settings_from_config(cls, cfg, key)
        block = list(s.lacey_block)
        if len(block) != 3:
            raise ConfigError(f"config value {key}.lacey_block={block} is invalid: must be [bx, by, bz] "
                              f"(override it, e.g. {key}.lacey_block=[2,1,2])")
        s.lacey_block = tuple(checks.positive_int(f"{key}.lacey_block[{i}]", b)  # type: ignore[assignment]
                              for i, b in enumerate(block))
        checks.number(f"{key}.lacey_min_count", s.lacey_min_count, lo=1.0)
        checks.number(f"{key}.bed_quantile", s.bed_quantile, lo=0.5, hi=1.0, hi_open=True)
        checks.number(f"{key}.bubble_threshold", s.bubble_threshold, lo=0.0, hi=0.6, lo_open=True)
        return s

    def as_kwargs(self) -> dict[str, Any]:
        return {"block": self.lacey_block, "min_count": self.lacey_min_count, "bed_quantile": self.bed_quantile,
                "bubble_threshold": self.bubble_threshold}


def settings_from_config(cls: Any, cfg: Any, key: str) -> Any:
    """A settings dataclass from a config node (lists as tuples); an unknown key is refused by name."""
    values = dict(cfg) if cfg is not None else {}
    checks.known_keys(key, values, cls.__dataclass_fields__)
    return cls(**{k: (tuple(v) if OmegaConf.is_list(v) or isinstance(v, list) else v) for k, v in values.items()})
