"""OmegaConf resolvers used in `conf/` (registered once, on import of `neuraldem.config`)."""

from __future__ import annotations

from omegaconf import OmegaConf

from neuraldem import paths


def gpus_per_node(accelerator: object, devices: object) -> object:
    """A Slurm job's GPUs per node for a trainer: its devices on GPUs, none on CPUs (asking a CPU partition for
    GPUs is refused by sbatch: "Invalid generic resource (gres) specification")."""
    return devices if str(accelerator) in ("gpu", "cuda") else None


def register_resolvers() -> None:
    resolvers = {
        "nd_data_dir": lambda: str(paths.data_dir()),
        "nd_results_dir": lambda: str(paths.results_dir()),
        "nd_gpus_per_node": gpus_per_node,
    }
    for name, fn in resolvers.items():
        if not OmegaConf.has_resolver(name):
            OmegaConf.register_new_resolver(name, fn)
