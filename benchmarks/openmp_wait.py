"""What an OpenMP parallel region costs to start, and how long its idle workers spin, under the
environment this process was started with (Numba's "omp" layer: the runtime the kernels use).

    python benchmarks/openmp_wait.py                                  # the CLI's default (openmp_env.py)
    OMP_WAIT_POLICY=PASSIVE python benchmarks/openmp_wait.py          # sleep at once
    OMP_WAIT_POLICY=ACTIVE python benchmarks/openmp_wait.py           # spin (libgomp: ~forever)
    OMP_WAIT_POLICY=PASSIVE GOMP_SPINCOUNT=100000 python benchmarks/openmp_wait.py

Prints JSON: `region_us`, the median wall time of an empty two-thread region run back to back
(the workers' wake-up when they sleep between regions); `spin_ms`, the CPU time the workers spend
after one region before they sleep (from /proc's per-thread schedstat, over 20 regions 50 ms
apart); and `spin_ms_two_teams`, the same while a second thread's team exists and idles, as the
live engine's tracker and mapper each have one: libgomp then cuts the spin short itself (more of
its threads than cores).
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from pathlib import Path

from splat_core.openmp_env import openmp_defaults

openmp_defaults()   # as the CLI, before numba loads its runtime

import numpy as np  # noqa: E402
from numba import njit, prange  # noqa: E402
import numba  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine_line  # noqa: E402


@njit(parallel=True, nogil=True)
def _touch(a):
    for i in prange(a.shape[0]):
        a[i] += 1.0


def _workers_cpu() -> float:
    """CPU seconds of every thread of this process but the main one."""
    total = 0
    for task in Path(f"/proc/{os.getpid()}/task").iterdir():
        if task.name != str(os.getpid()):
            total += int((task / "schedstat").read_text().split()[0])
    return total / 1e9


def _spin_ms(a) -> float:
    before = _workers_cpu()
    for _ in range(20):
        _touch(a)
        time.sleep(0.05)
    return (_workers_cpu() - before) / 20 * 1e3


def main() -> None:
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    a = np.zeros(numba.get_num_threads())
    _touch(a)
    waits = []
    for _ in range(200):
        start = time.perf_counter()
        _touch(a)
        waits.append(time.perf_counter() - start)
    alone = _spin_ms(a)
    idle, ready = threading.Event(), threading.Event()

    def second_team():
        _touch(np.zeros(2))
        ready.set()
        idle.wait()
    threading.Thread(target=second_team, daemon=True).start()
    ready.wait()
    two = _spin_ms(a)
    idle.set()
    print(json.dumps({"machine": machine_line(), "threading_layer": numba.threading_layer(),
                      "OMP_WAIT_POLICY": os.environ.get("OMP_WAIT_POLICY"),
                      "GOMP_SPINCOUNT": os.environ.get("GOMP_SPINCOUNT"), "threads": numba.get_num_threads(),
                      "region_us": round(float(np.median(waits)) * 1e6, 1), "spin_ms": round(alone, 3),
                      "spin_ms_two_teams": round(two, 3)}))


if __name__ == "__main__":
    main()
