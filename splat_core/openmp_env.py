"""How the OpenMP runtime's idle threads wait: set in the environment before torch is imported.

Torch loads its bundled libgomp, and Numba's "omp" threading layer runs its parallel regions on that
same runtime (gdb backtraces of a live run: docs/history/2026-12-07-worker-and-tolerance.md). It
reads OMP_WAIT_POLICY and GOMP_SPINCOUNT once, when it loads. Between two parallel regions (a
mapping iteration runs tens of them: the rasterizer's kernels, the loss, torch's element-wise work)
a worker thread either spins or sleeps:

- OMP_WAIT_POLICY=PASSIVE: it sleeps at once, so idle workers of one thread's team never take the
  cores of another's, but every region then waits for its workers to wake (~70 us a region on the
  2-core Intel Xeon measured, against ~2 us for a spinning worker);
- GOMP_SPINCOUNT=10000 on top of it: it spins ~0.2 ms first (libgomp's unit is one `pause` loop:
  ~15 ns there), long enough to bridge the gaps inside an iteration, short enough that a thread
  left idle sleeps almost at once. A mapping iteration on two cores took 10 % less time than with
  PASSIVE alone, and the sequential engine's frames 4-10 % less, outputs the same bit for bit
  (docs/benchmarks.md, "OpenMP workers").

Where the runtime manages more threads than there are cores (the live engine: the tracker's and
the mapper's teams, each alive once its thread has run a two-thread region), libgomp cuts the spin
short by itself, so the live engine, and the viewer that runs it, wait as with PASSIVE alone. A
user's own setting of either variable wins: then neither is changed.
"""

from __future__ import annotations

import os

WAIT_POLICY = "PASSIVE"
SPIN_COUNT = "10000"


def openmp_defaults(environ=os.environ) -> None:
    """Set OMP_WAIT_POLICY and GOMP_SPINCOUNT (see the module doc) unless the user set either."""
    if "OMP_WAIT_POLICY" in environ or "GOMP_SPINCOUNT" in environ:
        return
    environ["OMP_WAIT_POLICY"] = WAIT_POLICY
    environ["GOMP_SPINCOUNT"] = SPIN_COUNT
