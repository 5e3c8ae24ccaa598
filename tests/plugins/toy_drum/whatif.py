"""The toy drum's what-if: the synthetic stand-in's answer (a model of the toy would answer here)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from toy_drum.solver import dynamic_repose_deg


def add_options(p: argparse.ArgumentParser) -> None:
    """No options of its own."""


def answer(point: dict[str, float], model_name: str, out: Path, args: argparse.Namespace) -> dict[str, Any]:
    return {"scene": "toy_drum", "model": model_name, "parameters": point, "warnings": [],
            "dynamic_repose_deg": dynamic_repose_deg(point["speed"], point["friction"])}


def table(answer: dict[str, Any]) -> str:
    return f"| dynamic angle of repose [deg] | {answer['dynamic_repose_deg']:.2f} |"
