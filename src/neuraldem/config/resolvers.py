"""OmegaConf resolvers used in `conf/` (registered once, on import of `neuraldem.config`)."""

from __future__ import annotations

from omegaconf import OmegaConf

from neuraldem import paths


def register_resolvers() -> None:
    resolvers = {
        "nd_data_dir": lambda: str(paths.data_dir()),
        "nd_results_dir": lambda: str(paths.results_dir()),
    }
    for name, fn in resolvers.items():
        if not OmegaConf.has_resolver(name):
            OmegaConf.register_new_resolver(name, fn)
