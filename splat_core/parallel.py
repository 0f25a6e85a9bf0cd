"""Numba's parallel runtime from several threads (docs/design.md, the renderer contract), and
splitting the cores between them; and the vector width the kernels are compiled for.

Numba's "workqueue" threading layer must not be entered from two threads at once; its "omp" and
"tbb" layers are thread-safe (Numba's documentation on threading layers). Every Numba-parallel
call (the CPU rasterizer, gsply's kernels in the map writers) runs inside `numba_lock()`: the
one lock below while the layer in use is not thread-safe (or before any parallel region has run,
when the layer is not chosen yet), nothing otherwise. So the live engine's tracker and mapper,
the SLAM worker and the viewer's renders can run kernels at the same time where that is safe.
"""

from __future__ import annotations

import contextlib
import os
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


def prefer_512_bit_vectors() -> bool:
    """Let LLVM vectorise the Numba kernels 512 bits wide on an x86 CPU with AVX-512.

    LLVM's tuning for Intel cores with AVX-512 prefers 256-bit vectors ("prefer-256-bit", against
    the clock slowdown of early AVX-512 parts), so the kernels' 16-lane pixel rows ran as two ymm
    halves. Turning that preference off (one of the target features Numba compiles for) made the
    rasterizer's forward and backward kernels 14-17 % faster on a 2-core Intel Xeon
    (docs/benchmarks.md, "Renderer"), with the same results bit for bit (each lane computes what it
    did). Where the tuning does not prefer 256 bits (the AMD EPYC of earlier measurements already
    compiled a row into one zmm register) nothing changes.

    Takes effect only before Numba's CPU target exists (its first `@njit`): every module with
    kernels imports this one first. A user's NUMBA_CPU_NAME or NUMBA_CPU_FEATURES wins. Returns
    whether the setting is in effect.
    """
    import numba

    if os.environ.get("NUMBA_CPU_NAME") or os.environ.get("NUMBA_CPU_FEATURES"):
        return False
    if numba.config.CPU_FEATURES is None:
        from llvmlite import binding as llvm
        try:
            features = llvm.get_host_cpu_features()
        except RuntimeError:       # not an x86 host LLVM knows the features of
            return False
        if not (features.get("avx512f") and numba.config.ENABLE_AVX):
            return False
        numba.config.CPU_FEATURES = features.flatten() + ",-prefer-256-bit"
    return numba.config.CPU_FEATURES.endswith(",-prefer-256-bit")


prefer_512_bit_vectors()
