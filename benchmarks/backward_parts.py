"""Where the CPU rasterizer's backward kernel spends its time: the kernel against copies of itself
with one part of its per-row work taken out, paired, on a real mapping step's inputs.

    python benchmarks/mapper_profile.py --input ../shared/data/sun3d_3dmatch_fragment1 --frame 30 \
        --config live --engine live --iterations 20 --save f1_30.pt
    OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 python benchmarks/backward_parts.py --load f1_30.pt

Replays the saved step (mapper_profile.py's replay) and keeps the inputs of its first `--calls`
backward kernel calls. Each variant is the kernel's own source (`splat_core/render/cpu.py`,
`_backward_kernel`) with one substitution, compiled beside it:

    no exp             G = exp(power) replaced by a multiply (the vectorised float32 exp's cost)
    no division        1 / (1 - a) replaced by an add
    no geometry sums   the five per-lane gradient sums of the mean and conic (g_pow terms) left out
    no lane sums       the per-Gaussian sums over the lanes, after its rows, left out

A variant's outputs are wrong by design: it measures what the part costs, nothing else. Per
repeat, every kernel runs on the same inputs, in alternating order; prints each kernel's median
(ms per call) and the median of the paired ratios variant / kernel (a ratio of 0.80: that part is
~20 % of the kernel). One thread by default (NUMBA_NUM_THREADS=1), as mapper_profile.py's
`--clock cpu`.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from splat_core.openmp_env import openmp_defaults  # noqa: E402
openmp_defaults()   # as the CLI, before torch: how idle OpenMP threads wait
os.environ.setdefault("NUMBA_CACHE_DIR", tempfile.mkdtemp(prefix="backward_parts_"))   # variants: not in the cache

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, machine_line  # noqa: E402

sys.path.insert(0, str(ROOT))

GEOMETRY = ["gl[_G_MX * TILE + i] -= g_pow * (A * dx + B * dy)", "gl[_G_MY * TILE + i] -= g_pow * (C * dy + B * dx)",
            "gl[_G_A * TILE + i] -= g_pow * half * dx * dx", "gl[_G_B * TILE + i] -= g_pow * dx * dy",
            "gl[_G_C * TILE + i] -= g_pow * half * dy * dy"]
VARIANTS = {
    "no exp": [("G = _exp(power)", "G = power * power")],
    "no division": [("inv = one / (one - a)", "inv = one + a")],
    "no geometry sums": [(line, "pass") for line in GEOMETRY],
    "no lane sums": [("for i in range(ia, ib + 1):\n                a0 +=", "for i in range(ia, ia):\n                a0 +=")],
}


def variant(cpu, name: str, substitutions):
    """The backward kernel compiled again from its source with `substitutions` made."""
    from numba import njit

    source = inspect.getsource(cpu._backward_kernel.py_func)
    source = source[source.index("def _backward_kernel"):]      # without its decorator (cache=True)
    for old, new in substitutions:
        if old not in source:
            raise SystemExit(f"backward_parts.py: the kernel no longer has {old!r}: update VARIANTS ({name})")
        source = source.replace(old, new)
    namespace = dict(vars(cpu))
    exec(compile(source, f"<backward: {name}>", "exec"), namespace)
    return njit(parallel=True, nogil=True, error_model="numpy", fastmath={"contract"})(
        namespace["_backward_kernel"])


def capture(path: str, calls: int) -> list[tuple]:
    import torch

    import mapper_profile
    from splat_core.render import cpu

    saved, kernel = [], cpu._backward_kernel

    def keep(*args):
        if len(saved) < calls:
            saved.append(tuple(a.copy() if isinstance(a, np.ndarray) else a for a in args))
        return kernel(*args)
    cpu._backward_kernel = keep
    try:
        mapper_profile.replay(torch.load(path, weights_only=False), 20, 0)
    finally:
        cpu._backward_kernel = kernel
    return saved


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--load", required=True, help="a mapping step saved by mapper_profile.py --save")
    p.add_argument("--calls", type=int, default=3, help="backward calls of the replay to time")
    p.add_argument("--repeats", type=int, default=15)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()

    import numba

    from splat_core.render import cpu

    inputs = capture(args.load, args.calls)
    kernels = {"kernel": cpu._backward_kernel}
    kernels.update({name: variant(cpu, name, subs) for name, subs in VARIANTS.items()})
    numba.set_parallel_chunksize(1)          # as the rasterizer calls it (_TileChunks)
    for fn in kernels.values():              # compile
        fn(*inputs[0][:-1], np.empty_like(inputs[0][-1]))
    times = {name: [] for name in kernels}
    for rep in range(args.repeats):
        order = list(kernels.items())
        for name, fn in (order if rep % 2 == 0 else order[::-1]):
            start = time.perf_counter()
            for a in inputs:
                fn(*a[:-1], np.empty_like(a[-1]))
            times[name].append((time.perf_counter() - start) / len(inputs) * 1e3)
    base = np.array(times["kernel"])
    result = {"machine": machine_line(), "threads": numba.get_num_threads(), "load": args.load,
              "intersections": int(inputs[0][4].shape[0]),
              "ms": {n: round(float(np.median(t)), 3) for n, t in times.items()},
              "ratio": {n: round(float(np.median(np.array(t) / base)), 3) for n, t in times.items() if n != "kernel"}}
    if args.json:
        print(json.dumps(result))
        return
    print(f"## Backward kernel parts · {result['machine']} · {result['threads']} thread(s) · "
          f"{result['intersections']} intersections a call\n")
    print("| kernel | ms per call (median) | paired ratio to the kernel | the part's share |")
    print("|---|---|---|---|")
    for name, ms in result["ms"].items():
        ratio = result["ratio"].get(name)
        print(f"| {name} | {ms:.2f} | {'-' if ratio is None else f'{ratio:.3f}'} | "
              f"{'-' if ratio is None else f'{1 - ratio:.0%}'} |")


if __name__ == "__main__":
    main()
