"""Hydra finds this plugin by its package (`hydra_plugins`): it adds to every Hydra command's search path the config
folders of scene plug-ins (`NEURALDEM_SCENES`, `neuraldem.scenes.config_dirs`) and then your user config folder
(`$NEURALDEM_CONFIG`, default `~/.config/neuraldem`, where `neuraldem scene new` writes scene files), so that
`neuraldem datagen data=<a plug-in's or your scene>` and `neuraldem train experiment=<its experiment>` compose them.
The packaged configs come first; a file of yours with a packaged name is refused before Hydra composes
(`neuraldem.config.user`), so nothing is shadowed silently."""

from __future__ import annotations

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin


class NeuraldemSearchPathPlugin(SearchPathPlugin):
    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        from neuraldem.paths import user_config_dir
        from neuraldem.scenes import config_dirs

        known = {str(e.path) for e in search_path.get_path()}
        for provider, folder in [*(("neuraldem-scene-plugin", d) for d in config_dirs()),
                                 ("neuraldem-user-config", user_config_dir())]:
            if f"file://{folder}" not in known:
                search_path.append(provider=provider, path=f"file://{folder}")
                known.add(f"file://{folder}")
