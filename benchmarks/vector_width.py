"""The Numba kernels compiled for 512-bit vectors (the default on AVX-512 x86) against 256-bit ones.

    python benchmarks/mapper_profile.py --input ../shared/data/7scenes_redkitchen_300 --frame 100 --save map100.pt
    python benchmarks/vector_width.py --load map100.pt --rounds 4

`splat_core.parallel.prefer_512_bit_vectors` turns off LLVM's "prefer-256-bit" tuning, which it
applies to Intel cores with AVX-512. Each round runs two child processes, one per width, in
alternating order: the 256-bit one with NUMBA_CPU_FEATURES set to the host's features as LLVM
reports them (what Numba compiles for without the setting; a user's NUMBA_CPU_FEATURES wins over it),
the 512-bit one without. Each child replays the saved mapping step (`--iterations`, default 20)
`--repeats` times after a warm-up and prints its medians: the whole step, and the rasterizer's
forward and backward kernels per iteration. Kernels compile into Numba's cache on a first run of
each width (the cache keys them by the target's features). Prints JSON: the machine, every child's
figures, and per width the median over rounds with the paired ratio 512 / 256.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, machine  # noqa: E402

sys.path.insert(0, str(ROOT))


def child(load: str, iterations: int, repeats: int) -> dict:
    import copy

    import numpy as np
    import torch

    from splat_core.gaussians import GaussianMap
    from splat_core.mapping import optimise_map
    from splat_core.parallel import prefer_512_bit_vectors
    from splat_core.render import cpu

    wide = prefer_512_bit_vectors()
    m0, window, intr, config, _, radius, rng0, renderer = torch.load(load, weights_only=False)
    steps, fwd, bwd = [], [], []
    original_forward, original_backward = cpu._forward, cpu._backward

    def forward(*a, **k):
        out = original_forward(*a, **k)
        fwd[-1] += cpu.last_stats["forward_kernel_ms"]
        return out

    def backward(*a, **k):
        out = original_backward(*a, **k)
        bwd[-1] += cpu.last_stats["backward_kernel_ms"]
        return out

    cpu._forward, cpu._backward = forward, backward
    for r in range(repeats + 1):            # the first is a warm-up (compiles on a first run)
        m = GaussianMap(*(m0.params[n].detach().clone() for n in m0.params), m0.birth_frame.clone())
        fwd.append(0.0)
        bwd.append(0.0)
        start = time.perf_counter()
        optimise_map(m, window, intr, config, iterations, radius, copy.deepcopy(rng0), renderer=renderer)
        steps.append(time.perf_counter() - start)
    return {"wide": wide, "step_ms": 1e3 * float(np.median(steps[1:])),
            "forward_kernel_ms_per_iteration": float(np.median(fwd[1:])) / iterations,
            "backward_kernel_ms_per_iteration": float(np.median(bwd[1:])) / iterations}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--load", required=True, help="a mapping step saved by mapper_profile.py --save")
    p.add_argument("--rounds", type=int, default=4)
    p.add_argument("--iterations", type=int, default=20)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child:
        print(json.dumps(child(args.load, args.iterations, args.repeats)))
        return
    from llvmlite import binding as llvm

    host = llvm.get_host_cpu_features()
    if not host.get("avx512f"):
        raise SystemExit("this CPU has no AVX-512: the kernels are compiled the same either way")
    envs = {"512": {k: v for k, v in os.environ.items() if k != "NUMBA_CPU_FEATURES"},
            "256": dict(os.environ, NUMBA_CPU_FEATURES=host.flatten())}
    cmd = [sys.executable, __file__, "--child", "--load", args.load, "--iterations", str(args.iterations),
           "--repeats", str(args.repeats)]
    runs = []
    load = os.getloadavg()[0]
    for r in range(args.rounds):
        for width in (("256", "512") if r % 2 == 0 else ("512", "256")):
            out = subprocess.run(cmd, env=envs[width], capture_output=True, text=True, check=True, cwd=ROOT)
            row = dict(json.loads(out.stdout.strip().splitlines()[-1]), width=width, round=r)
            if row["wide"] != (width == "512"):
                raise SystemExit(f"the {width}-bit child compiled for the other width: {row}")
            runs.append(row)
    import numpy as np

    summary = {}
    for key in ("step_ms", "forward_kernel_ms_per_iteration", "backward_kernel_ms_per_iteration"):
        a = {w: [x[key] for x in runs if x["width"] == w] for w in ("256", "512")}
        ratios = [b / c for b, c in zip(a["512"], a["256"])]
        summary[key] = {"256": float(np.median(a["256"])), "512": float(np.median(a["512"])),
                        "ratio_512_over_256": float(np.median(ratios)), "ratios": ratios}
    print(json.dumps({"machine": machine(), "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                      "load": [load, os.getloadavg()[0]], "map": Path(args.load).name,
                      "iterations": args.iterations, "repeats": args.repeats, "summary": summary,
                      "runs": runs}, indent=1))


if __name__ == "__main__":
    main()
