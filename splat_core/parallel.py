"""Numba's parallel runtime from several threads (docs/design.md, the renderer contract), and
splitting the cores between them.

Numba's "workqueue" threading layer must not be entered from two threads at once; its "omp" and
"tbb" layers are thread-safe (Numba's documentation on threading layers). Every Numba-parallel
call (the CPU rasterizer, gsply's kernels in the map writers) runs inside `numba_lock()`: the
one lock below while the layer in use is not thread-safe (or before any parallel region has run,
when the layer is not chosen yet), nothing otherwise. So the live engine's tracker and mapper,
the SLAM worker and the viewer's renders can run kernels at the same time where that is safe.
"""

from __future__ import annotations

import contextlib
import threading

NUMBA_LOCK = threading.Lock()
_THREAD_SAFE_LAYERS = ("omp", "tbb")
_layer_is_safe: bool | None = None


def numba_lock():
    """The context to hold around a Numba-parallel call (see the module docstring)."""
    global _layer_is_safe
    if _layer_is_safe is None:
        import numba
        try:
            _layer_is_safe = numba.threading_layer() in _THREAD_SAFE_LAYERS
        except ValueError:          # no parallel region has run yet: the layer is not chosen
            return NUMBA_LOCK
    return contextlib.nullcontext() if _layer_is_safe else NUMBA_LOCK
