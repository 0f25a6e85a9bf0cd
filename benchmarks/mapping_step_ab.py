"""A whole mapping step (`optimise_map`) with this checkout's renderer and mapping code against
another checkout's, paired, in one process, on a saved real step.

    python benchmarks/mapper_profile.py --input ../shared/data/7scenes_redkitchen_300 --frame 100 --save map100.pt
    OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 python benchmarks/mapping_step_ab.py --load map100.pt --before ../before

Loads the other checkout's `splat_core/render` package (its `render`, its CPU rasterizer and
projection) as `splat_core._before_render` and its `splat_core/mapping.py` as
`splat_core._before_mapping`, beside this checkout's (the rest of the package, the loss
included, is this checkout's: both sides use it). Then replays the saved step `--repeats` times
with each, in alternating order, on fresh copies of the map and the same random state, asserts
that both leave the map bit for bit the same (`--no-check` for a change not meant to keep it),
and prints the medians (ms per iteration) and the median of the paired ratios (this over
before) with their quartiles: on a loaded machine, replays taken moments apart share its load,
where separate runs do not. `--clock cpu` (default): the process's CPU time (one thread:
OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1).
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import os
import sys
import time
from pathlib import Path

from splat_core.openmp_env import openmp_defaults  # noqa: E402
openmp_defaults()   # as the CLI, before torch: how idle OpenMP threads wait

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, machine_line  # noqa: E402

sys.path.insert(0, str(ROOT))


def load_before(checkout: str):
    """(render package, mapping module) of the other checkout, as modules of this package."""
    import splat_core  # noqa: F401  (the package the other modules join)

    root = Path(checkout) / "splat_core"
    spec = importlib.util.spec_from_file_location("splat_core._before_render", root / "render" / "__init__.py",
                                                  submodule_search_locations=[str(root / "render")])
    render = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = render
    spec.loader.exec_module(render)
    spec = importlib.util.spec_from_file_location("splat_core._before_mapping", root / "mapping.py")
    mapping = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mapping
    spec.loader.exec_module(mapping)
    # Its mapping code draws tiles and frustum tests with its own render package's helpers.
    for name in ("tile_grid", "tile_pixels", "frustum_mask"):
        if hasattr(mapping, name) and hasattr(render, name):
            setattr(mapping, name, getattr(render, name))
    return render, mapping


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--load", required=True, help="a mapping step saved by mapper_profile.py --save")
    p.add_argument("--before", required=True, help="the other checkout")
    p.add_argument("--iterations", type=int, default=10)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--clock", choices=("cpu", "wall"), default="cpu")
    p.add_argument("--no-check", action="store_true")
    args = p.parse_args()
    import torch

    from splat_core import mapping
    from splat_core.gaussians import GaussianMap

    before_render, before_mapping = load_before(args.before)
    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    m0, window, intr, config, _, radius, rng0, renderer = torch.load(args.load, weights_only=False)
    sides = {"this": (mapping.optimise_map, renderer),
             "before": (before_mapping.optimise_map,
                        before_render.Renderer(near=renderer.near, backend=renderer.backend))}
    times = {"this": [], "before": []}
    load = os.getloadavg()[0]
    for r in range(args.repeats + 1):            # the first pair warms up (Numba's cache, allocator)
        maps = {}
        for name in (("this", "before") if r % 2 else ("before", "this")):
            optimise, rend = sides[name]
            m = GaussianMap(*(m0.params[n].detach().clone() for n in m0.params), m0.birth_frame.clone())
            start = clock()
            optimise(m, window, intr, config, args.iterations, radius, copy.deepcopy(rng0), renderer=rend)
            elapsed = clock() - start
            maps[name] = m
            if r:
                times[name].append(elapsed / args.iterations)
        if not args.no_check:
            assert all(torch.equal(maps["this"].params[n], maps["before"].params[n]) for n in m0.params), \
                "the step's map differs from the other checkout's"
    print(f"# {Path(args.load).name} · before: {args.before} · {machine_line()} · {args.clock} clock · "
          f"load {load:.2f} -> {os.getloadavg()[0]:.2f} · {args.iterations} iterations x {args.repeats} pairs · "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}"
          + ("" if args.no_check else " · maps bit for bit equal"))
    a, b = np.array(times["this"]), np.array(times["before"])
    ratio = a / b
    lo, hi = np.percentile(ratio, [25, 75])
    print("| mapping iteration | this (ms, median) | before (ms, median) | paired ratio this / before (median) "
          "| quartiles |")
    print("|---|---|---|---|---|")
    print(f"| whole step / iterations | {np.median(a) * 1e3:.2f} | {np.median(b) * 1e3:.2f} | {np.median(ratio):.3f} "
          f"| {lo:.3f}-{hi:.3f} |")


if __name__ == "__main__":
    main()
