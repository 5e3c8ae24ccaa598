"""Hydra/OmegaConf glue: resolvers for our paths, value checks, and the entry-point wrapper."""

from neuraldem.config.resolvers import register_resolvers

register_resolvers()
