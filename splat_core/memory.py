"""Giving freed memory back to the system during a long run.

Torch and numpy allocate and free image- and map-sized buffers every iteration. glibc's malloc
serves many of them from its heaps rather than fresh mappings (its mmap threshold rises to the
largest buffer freed so far), and a heap it cannot shrink from the top keeps the freed pages: on
a 300-frame run at 160x120 that was 0.1 MB of RSS per frame while the keyframes and the map grew
by 0.03 (benchmarks/long_run.py memory). `malloc_trim(0)` returns those free pages; the pipeline
calls it every few frames. Elsewhere than glibc this does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.cache
def _malloc_trim():
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
        return libc.malloc_trim if libc is not None and hasattr(libc, "malloc_trim") else None
    except OSError:
        return None


def release_free_memory() -> bool:
    """Return freed heap pages to the system (glibc); True when there was something to call."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True
