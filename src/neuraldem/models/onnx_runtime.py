"""Nets exported to ONNX and answered by ONNX Runtime: a what-if without importing torch.

Why: on a 2-core CPU, importing torch takes ~1.3 s (with Lightning ~4.5 s), many times the hopper field model's
whole right-sized answer (0.08 s); ONNX Runtime imports in ~0.1 s and answers within 1.2x of eager torch at one
thread, 2x at two (results/hopper/speed/runtime.md, `neuraldem bench runtime`). A released model carries
`field.onnx` beside `field.pt`; the answer path loads the first when the runtime is installed and the second
otherwise, and a test checks both give the same answers (tests/models/test_onnx_runtime.py).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from neuraldem.errors import ConfigError

RUNTIMES = ("onnx", "torch")
OPSET = 17
MAX_THREADS = 64


def require_onnxruntime(key: str = "runtime") -> Any:
    """The onnxruntime module; one line naming the option and the fix when it is not installed."""
    try:
        import onnxruntime
    except ImportError:
        raise ConfigError(f"{key}=onnx needs ONNX Runtime, which is not installed",
                          f"pip install onnxruntime (or {key}=torch)") from None
    return onnxruntime


def installed() -> bool:
    """Whether ONNX Runtime imports here (what runtime=auto chooses by)."""
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        return False
    return True


def check_threads(threads: int, key: str = "threads") -> int:
    if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= MAX_THREADS:
        raise ConfigError(f"{key}={threads!r} is invalid: give a whole number of threads in 1 .. {MAX_THREADS}",
                          f"e.g. {key}=1 (one thread answered fastest on a 2-core machine)")
    return threads


def export_onnx(net: Any, inputs: Mapping[str, Any], outputs: Sequence[str], path: Path,
                dynamic: Mapping[str, Mapping[int, str]]) -> Path:
    """Export `net(**inputs) -> {name: tensor}` to `path` with the named dynamic axes (e.g. batch, queries)."""
    import torch

    try:
        import onnx  # noqa: F401  (torch's exporter writes through it)
    except ImportError:
        raise ConfigError("exporting a model to ONNX needs the onnx package", "pip install onnx") from None

    class Outputs(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.net = net

        def forward(self, *args: Any) -> tuple[Any, ...]:
            out = self.net(**dict(zip(inputs, args, strict=True)))
            return tuple(out[name] for name in outputs)

    path = Path(path)
    tmp = path.with_suffix(".tmp")
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the tracer's notes on shape-dependent branches: the check below decides
        torch.onnx.export(Outputs().eval(), tuple(inputs.values()), str(tmp), input_names=list(inputs),
                          output_names=list(outputs), dynamic_axes={**dynamic}, opset_version=OPSET, dynamo=False)
    tmp.replace(path)
    return path


class OnnxNet:
    """An exported net: `net(name=array, ...)` -> {output name: array}, float32 in and out."""

    def __init__(self, path: Path, threads: int = 1):
        ort = require_onnxruntime()
        options = ort.SessionOptions()
        options.intra_op_num_threads = check_threads(threads)
        options.inter_op_num_threads = 1
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        try:
            self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        except Exception as err:  # noqa: BLE001 - any unreadable file
            from neuraldem.errors import DataError

            raise DataError(f"{path} is not a readable ONNX model ({type(err).__name__})",
                            "release the model again (neuraldem release ...)") from None
        self.outputs = [o.name for o in self.session.get_outputs()]

    def __call__(self, **inputs: np.ndarray) -> dict[str, np.ndarray]:
        feed = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in inputs.items()}
        return dict(zip(self.outputs, self.session.run(self.outputs, feed), strict=True))
