"""One lock around Numba's parallel runtime, which must not be entered from two threads at once
(DESIGN.md §4). The CPU rasterizer holds it for every kernel call; so do the map writers and
readers whose gsply kernels are parallel (compressed PLY, SPZ), since a viewer button may export
while the SLAM worker renders."""

from __future__ import annotations

import threading

NUMBA_LOCK = threading.Lock()
