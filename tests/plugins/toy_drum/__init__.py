"""A toy scene plug-in for the tests: a rotating drum whose "solver" is a SYNTHETIC STAND-IN (a closed-form
dynamic angle of repose, no particles), so that registering a scene from a folder outside the package, its
datagen, its what-if and its explorer page can be tested in seconds. It is not physics to trust.

It is registered with `NEURALDEM_SCENES=<this folder>`; its Hydra configs are in `conf/`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from neuraldem.scenes import Scene
from neuraldem.scenes.parameters import Parameter, ParameterTable

PARAMETERS = ParameterTable((
    Parameter("speed", "rpm", 0.0, 60.0, "drum rotation speed"),
    Parameter("friction", "", 0.0, 1.5, "sliding friction coefficient"),
))


def pipeline(data_cfg: Any) -> Any:
    from toy_drum.datagen import ToyDrumPipeline

    return ToyDrumPipeline(data_cfg)


def evaluate(cfg: Any) -> None:
    raise NotImplementedError("the toy scene has no model to evaluate")


def evaluate_run(cfg: Any, ckpt: Path) -> dict[str, Any]:
    raise NotImplementedError("the toy scene has no model to evaluate")


SCENE = Scene(kind="toy_drum", description="rotating drum (synthetic stand-in, for tests)",
              experiment="experiment=toy_drum", parameters=PARAMETERS, pipeline=pipeline, evaluate=evaluate,
              evaluate_run=evaluate_run, aliases=("drum",), whatif="toy_drum.whatif", page="toy_drum.page",
              reports={"drum-table": ("toy_drum.report", "the toy drum's runs side by side")})
