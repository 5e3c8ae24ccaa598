"""Hydra finds this plugin by its package (`hydra_plugins`): it adds the config folders of scene plug-ins
(`NEURALDEM_SCENES`, `neuraldem.scenes.config_dirs`) to every Hydra command's search path, so that
`neuraldem datagen data=<a plug-in's dataset>` and `neuraldem train experiment=<its experiment>` compose them."""

from __future__ import annotations

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin


class NeuraldemSearchPathPlugin(SearchPathPlugin):
    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        from neuraldem.scenes import config_dirs

        known = {str(e.path) for e in search_path.get_path()}
        for folder in config_dirs():
            if f"file://{folder}" not in known:
                search_path.append(provider="neuraldem-scene-plugin", path=f"file://{folder}")
