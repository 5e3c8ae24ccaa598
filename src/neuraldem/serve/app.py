"""The explorer's server: it serves the pages the scenes bring, one per scene (`Scene.page`).

A page module has `TITLE`, `prepare(model_name, dataset, near)` (load once per server: the model, verified,
and what its sessions share) and `page(shared)` (one browser session's view). `neuraldem serve` hands this
module the pages as {route: (scene kind, page module)}. A page whose scene has no shipped model is left out
with a note; a model file that is missing or damaged stops the server with the one-line DataError.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

from neuraldem import pretrained
from neuraldem.errors import ConfigError

Pages = dict[str, tuple[str, str]]  # route -> (scene kind, page module)


@dataclass
class ServedPage:
    route: str
    module: ModuleType
    shared: Any


def model_for(kind: str, model_name: str | None) -> tuple[str | None, str]:
    """The model a page shows (`model=` when it is of the page's kind) or None and why the page is off."""
    if model_name is not None and pretrained.load(model_name).kind == kind:
        return model_name, ""
    try:
        return pretrained.default_for(kind), ""
    except ConfigError as err:
        return None, f"page off: {err.problem}"


def prepare_pages(pages: Pages, model_name: str | None, dataset: Path | None, near: float,
                  only: list[str] | None = None) -> tuple[list[ServedPage], list[str]]:
    """Load every page that has a model (or those in `only`); notes say which are off and why."""
    served, notes = [], []
    for route in only or list(pages):
        if route not in pages:
            raise ConfigError(f"unknown page {route!r}", f"choose from {', '.join(pages)}")
        kind, module_name = pages[route]
        module = importlib.import_module(module_name)
        name, why = model_for(kind, model_name)
        if name is None:
            notes.append(f"{route}: {why}")
            continue
        served.append(ServedPage(route, module, module.prepare(name, dataset, near)))
    if not served:
        raise ConfigError("no page can be served: " + "; ".join(notes),
                          "install neuraldem with its shipped models, or pass model=NAME")
    return served, notes


def index_html(pages: list[ServedPage], notes: list[str]) -> str:
    links = "".join(f'<li><a href="/{p.route}">{p.module.TITLE}</a></li>' for p in pages)
    off = "".join(f"<li>{n}</li>" for n in notes)
    return f"<h2>neuraldem explorer</h2><ul>{links}</ul>" + (f"<p>not served:</p><ul>{off}</ul>" if off else "")


def serve(pages: list[ServedPage], notes: list[str], host: str, port: int, show: bool) -> Any:
    """Serve the pages at http://host:port/<route> (blocks until stopped)."""
    import panel as pn

    pn.extension("plotly")
    routes: dict[str, Any] = {p.route: (lambda p=p: p.module.page(p.shared)) for p in pages}
    routes["/"] = lambda: pn.pane.HTML(index_html(pages, notes))
    origins = [f"{host}:{port}", f"localhost:{port}", f"127.0.0.1:{port}"]
    return pn.serve(routes, port=port, address=host, show=show, title="neuraldem explorer",
                    websocket_origin=origins, print=False)
