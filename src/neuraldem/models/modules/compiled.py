"""Small per-step numerics of a bed rollout compiled by Numba: the same arithmetic as their NumPy form, bit for
bit, in one call each.

Why: a bed rollout advects its mixing concentration (a few sub-steps over a few hundred cells) and projects its
solid volume every step. In NumPy each is tens of array calls of a few microseconds, together as much as a third
of a what-if answer (`neuraldem bench whatif_fb`); compiled, the same loops take microseconds.

Bit for bit: every value is the same IEEE operation on the same operands as the NumPy form (no fast-math, so no
reordering and no fused multiply-adds), and every sum adds in the order NumPy's does (a reduction over axis 0,
a cumulative sum: the first term, then each next one). `tests/models/modules/test_compiled.py` checks both
kernels against their NumPy form on random fields and the edge cases. Without Numba installed `available()` is
False and the NumPy forms run. The kernels themselves are in `_numba_kernels`, imported on first use
(importing Numba costs ~0.2 s).

- `advection_substeps`: `conservative_advection._Grid.substep`, n times;
- `water_fill_rows`: `scenes.fluidized_bed.surrogate.autoregressive._water_fill_numpy`.
"""

from __future__ import annotations

import importlib.util
import threading
from types import ModuleType

import numpy as np

_numba_installed = importlib.util.find_spec("numba") is not None
_lock = threading.Lock()
_kernels: ModuleType | None = None
_warming: threading.Thread | None = None


def available() -> bool:
    """Whether Numba is installed (without importing it)."""
    return _numba_installed


def kernels() -> ModuleType:
    """The compiled kernels (`_numba_kernels`), imported and loaded once; waits for a warm-up under way."""
    global _kernels
    if _kernels is None:
        with _lock:
            if _kernels is None:
                from neuraldem.models.modules import _numba_kernels

                _call_each_kernel(_numba_kernels)
                _kernels = _numba_kernels
    return _kernels


def warm_up_in_background() -> None:
    """Load the kernels on a daemon thread. Importing Numba and a process's first call of a compiled function
    cost ~0.5 s (its runtime starts, the cached machine code is read; ~2 s more where nothing is cached yet),
    most of it in LLVM with the GIL released: a one-off command (`neuraldem predict fluidized_bed`) pays it while
    it imports torch and reads its model, not in its rollout. Idempotent."""
    global _warming
    if not _numba_installed or _kernels is not None or _warming is not None:
        return
    _warming = threading.Thread(target=kernels, name="numba-warm-up", daemon=True)
    _warming.start()


def _call_each_kernel(k: ModuleType) -> None:
    """One valid call of each kernel with the argument types of a rollout (compiles or loads its machine code)."""
    one, pair = np.ones(1), np.zeros(2)
    index = np.zeros((1, 1), dtype=np.intp)
    # one cell, one face, no correction (the kernels do not check bounds)
    k.advection_substeps(1, one, one, one, pair, one, one, 0.0, np.zeros(2, dtype=np.intp), index, index, index)
    k.water_fill_rows(np.ones((1, 2)), np.ones((1, 1)), 1.0)
