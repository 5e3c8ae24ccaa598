"""The toy drum's explorer page: one number for the model's default point."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from toy_drum.solver import dynamic_repose_deg

TITLE = "Rotating drum (synthetic stand-in)"


def prepare(model_name: str, dataset: Path | None, near: float) -> dict[str, Any]:
    return {"model": model_name, "answer": dynamic_repose_deg(10.0, 0.5)}


def page(shared: dict[str, Any]) -> Any:
    import panel as pn

    return pn.pane.HTML(f"<p id='toy'>{shared['answer']:.2f} deg ({shared['model']})</p>")
