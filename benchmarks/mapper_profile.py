"""Where a mapper step's time goes: one mapping step (`optimise_map`) on a real map, split into its
parts, and the whole step per frame (densify, window, prune, optimise) of a sequential run.

    python benchmarks/mapper_profile.py --input ../shared/data/7scenes_redkitchen_300 --frame 100
    python benchmarks/mapper_profile.py --input ../shared/data/sun3d_3dmatch_fragment2 --frame 40 --threads 1,2
    OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 python benchmarks/mapper_profile.py --clock cpu --config live --engine live

Runs `--engine` (default sequential) on `--config` (default `cpu`) up to frame `--frame`, timing
map_frame's parts (and publish, loop closure) on every frame after 0, and keeps a copy of the map,
the window and the random state that frame's `optimise_map` was called with. Then replays that
call `--repeats` times on copies of the map with `--iterations` (default: the preset's, and the
`live` preset's 20 for a keyframe step), timing each part by wrapping the functions that do it
(projection, the rasterizer's binning, sort and kernels, the loss, each backward, Adam, pruning);
what no wrapper covers (the subset's gather, Adam's construction, autograd's glue, the
write-back) is the remainder. A replay's outputs equal
the run's own step (same map, window and random state), so the figures are those of real work.
Prints medians over the repeats: ms per step and per iteration.
"""

from __future__ import annotations

import argparse
import copy
import functools
import os
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from splat_core.openmp_env import openmp_defaults  # noqa: E402
openmp_defaults()   # as the CLI, before torch: how idle OpenMP threads wait

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, machine_line  # noqa: E402

sys.path.insert(0, str(ROOT))

TIMES: dict = defaultdict(float)
COUNTS: dict = defaultdict(int)
ACTIVE = {"on": False}
CLOCK = {"now": time.perf_counter, "part": time.perf_counter}   # --clock cpu: CPU seconds (see --help)


def now() -> float:
    return CLOCK["now"]()


def timed(owner, name: str, label: str, static: bool = False) -> None:
    original = owner.__dict__[name] if static else getattr(owner, name)
    fn = original.__func__ if isinstance(original, staticmethod) else original

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if not ACTIVE["on"]:
            return fn(*args, **kwargs)
        start = now()
        try:
            return fn(*args, **kwargs)
        finally:
            TIMES[label] += now() - start
            COUNTS[label] += 1
    setattr(owner, name, staticmethod(wrapper) if isinstance(original, staticmethod) else wrapper)


PARTS = [  # (label, what it covers); nested labels are included in their parent
    ("step", "optimise_map, whole call"),
    ("frusta", "the window's frustum tests (per call)"),
    ("draw tiles", "draw_tiles (per iteration)"),
    ("render", "Renderer.render: projection + rasterizer forward + background"),
    ("  project fwd", "projection kernel"),
    ("  raster fwd", "rasterizer forward (binning, sort, kernel)"),
    ("    bin+sort", "  of which: prepare, depth sort, gather, tile binning"),
    ("    fwd kernel", "  of which: the compositing kernel"),
    ("loss fwd", "mapping_loss (L1 + SSIM)"),
    ("backward", "loss.backward(), all of it"),
    ("  loss bwd", "the loss's backward (SSIM's)"),
    ("  raster bwd", "rasterizer backward"),
    ("    bwd kernel", "  of which: the kernel"),
    ("    reduce", "  of which: the per-Gaussian sums"),
    ("  project bwd", "projection backward"),
    ("adam", "optimizer.step (fused Adam)"),
    ("prune", "prune_mask + GaussianMap.prune inside the loop"),
]


def instrument() -> None:
    import torch

    from splat_core import gaussians, mapping
    from splat_core.losses import mapping_loss_cpu
    from splat_core.render import Renderer, cpu, project_cpu

    timed(mapping, "frustum_mask", "frusta")
    timed(mapping, "draw_tiles", "draw tiles")
    timed(Renderer, "render", "render")
    timed(project_cpu._ProjectIsotropicCPU, "forward", "  project fwd", static=True)
    timed(cpu, "_forward", "  raster fwd")
    timed(cpu, "_bin", "    bin+sort")
    timed(cpu, "_forward_kernel", "    fwd kernel")
    timed(cpu, "_backward_kernel", "    bwd kernel")
    timed(cpu, "_reduce_grads", "    reduce")
    timed(mapping, "mapping_loss", "loss fwd")
    timed(torch.Tensor, "backward", "backward")
    timed(mapping_loss_cpu._MappingLossCPU, "backward", "  loss bwd", static=True)
    timed(cpu._RasterizeCPU, "backward", "  raster bwd", static=True)
    timed(project_cpu._ProjectIsotropicCPU, "backward", "  project bwd", static=True)
    timed(torch.optim.Adam, "step", "adam")
    timed(mapping, "prune_mask", "prune")
    timed(gaussians.GaussianMap, "prune", "prune")


def capture(args):
    """Run to frame args.frame; return its optimise_map call's arguments (map copied) and the
    per-frame map_frame parts' times."""
    from splat_core import slam
    from splat_core.gaussians import GaussianMap
    from app.cli import splatam_main

    frame_parts: dict = defaultdict(list)
    state = {"frame": -1, "call": None}

    def part(name, label):
        original = getattr(slam.SplaTAM, name)

        @functools.wraps(original)
        def wrapper(self, *a, **k):
            start = CLOCK["part"]()
            try:
                return original(self, *a, **k)
            finally:
                if state["frame"] > 0:
                    frame_parts[label].append(CLOCK["part"]() - start)
        setattr(slam.SplaTAM, name, wrapper)

    original_map_frame = slam.SplaTAM.map_frame

    def map_frame(self, frame, w2c, t, *a, **k):
        state["frame"] = t
        return original_map_frame(self, frame, w2c, t, *a, **k)
    slam.SplaTAM.map_frame = map_frame
    for name, label in [("map_frame", "map_frame (all)"), ("densify", "densify"),
                        ("select_window", "select_window"), ("prune", "prune (iteration 0)"),
                        ("optimise", "optimise"), ("publish", "publish (copy)"),
                        ("close_loops", "close_loops")]:
        part(name, label)

    original_optimise = slam.optimise_map

    def optimise_map(m, window, intr, config, iterations, scene_radius, rng, renderer=None, stop=None):
        if state["frame"] >= args.frame and state["call"] is None:
            copy_m = GaussianMap(*(m.params[n].detach().clone() for n in m.params), m.birth_frame.clone())
            state["call"] = (copy_m, list(window), intr, config, iterations, scene_radius, copy.deepcopy(rng),
                             renderer)
        return original_optimise(m, window, intr, config, iterations, scene_radius, rng, renderer=renderer,
                                 stop=stop)
    slam.optimise_map = optimise_map

    out = tempfile.mkdtemp(prefix="mapper_profile_")
    splatam_main(["run", "--input", args.input, "--out", out, "--config", args.config, "--engine", args.engine,
                  "--device", "cpu", "--quiet", "--max-frames",
                  str(args.frame + (1 if args.engine == "sequential" else 15))])
    slam.optimise_map = original_optimise
    slam.SplaTAM.map_frame = original_map_frame
    if state["call"] is None:
        raise SystemExit(f"frame {args.frame} was not mapped (lost, or past the sequence's end)")
    return state["call"], frame_parts


def replay(call, iterations: int, repeats: int) -> tuple[list[dict], dict]:
    """Time `repeats` replays of the captured step with `iterations` iterations."""
    import torch

    from splat_core.gaussians import GaussianMap
    from splat_core.mapping import optimise_map
    from splat_core.render import cpu

    m0, window, intr, config, _, radius, rng0, renderer = call
    runs, stats = [], {}
    for r in range(repeats + 1):            # the first is a warm-up (Numba's cache, allocator)
        m = GaussianMap(*(m0.params[n].detach().clone() for n in m0.params), m0.birth_frame.clone())
        TIMES.clear()
        COUNTS.clear()
        ACTIVE["on"] = True
        start = now()
        try:
            st = optimise_map(m, window, intr, config, iterations, radius, copy.deepcopy(rng0), renderer=renderer)
        finally:
            ACTIVE["on"] = False
        TIMES["step"] = now() - start
        stats = dict(st, gaussians=len(m0), intersections=cpu.last_stats.get("intersections"),
                     live=cpu.last_stats.get("live"), torch_threads=torch.get_num_threads())
        if r:
            runs.append(dict(TIMES))
    return runs, stats


def table(runs: list[dict], iterations: int) -> list[str]:
    lines = ["| part | ms per step (median) | ms per iteration | share of the step |", "|---|---|---|---|"]
    step = float(np.median([r["step"] for r in runs]))
    covered = 0.0
    for label, what in PARTS:
        ms = float(np.median([r.get(label, 0.0) for r in runs])) * 1e3
        if label in ("frusta", "draw tiles", "render", "loss fwd", "backward", "adam", "prune"):
            covered += ms
        depth = (len(label) - len(label.lstrip())) // 2
        lines.append(f"| {'. ' * depth}{label.strip()} ({what}) | {ms:.1f} | {ms / iterations:.2f} | "
                     f"{ms / (step * 1e3):.0%} |")
    rest = step * 1e3 - covered
    lines.append(f"| rest (subset gather, Adam's construction, write-back, Python) | {rest:.1f} | "
                 f"{rest / iterations:.2f} | {rest / (step * 1e3):.0%} |")
    return lines


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--input", default=str(ROOT.parent / "shared" / "data" / "7scenes_redkitchen_300"))
    p.add_argument("--config", default="cpu")
    p.add_argument("--engine", default="sequential", help="live: map_frame's parts are the mapper thread's")
    p.add_argument("--frame", type=int, default=100,
                   help="the mapping step replayed: the first at this frame or after (live: a keyframe's; "
                        "the live run goes on 14 frames further to reach one)")
    p.add_argument("--iterations", default=None,
                   help="comma-separated iteration counts to replay (default: the preset's, and 20)")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--save", default=None, help="keep the captured step in this file (torch.save)")
    p.add_argument("--load", default=None, help="replay a step saved with --save instead of running to it")
    p.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                   help="cpu: CPU seconds instead of wall-clock ones: the replays' process time, map_frame's "
                        "parts' thread time. Run with OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1: kernels then run in "
                        "the calling thread, and a loaded machine's waits are left out")
    p.add_argument("--threads", default=None, help="comma-separated thread counts to replay under (torch and Numba)")
    p.add_argument("--torch-threads", type=int, default=None,
                   help="torch's intra-op threads in the replays (default: as --threads; Numba keeps --threads)")
    args = p.parse_args()
    import numba
    import torch

    load = os.getloadavg()
    if args.clock == "cpu":
        CLOCK["now"], CLOCK["part"] = time.process_time, time.thread_time
    if args.load:
        call, frame_parts = torch.load(args.load, weights_only=False), {}
    else:
        call, frame_parts = capture(args)
    if args.save:
        torch.save(call, args.save)
    instrument()
    iters = [int(i) for i in args.iterations.split(",")] if args.iterations else sorted({call[4], 20})
    threads = [int(t) for t in args.threads.split(",")] if args.threads else [torch.get_num_threads()]
    print(f"# {Path(args.input).name} · {args.config} · frame {args.frame} · {machine_line()} · "
          f"{args.clock} clock · load {load[0]:.2f} at the start, {os.getloadavg()[0]:.2f} after the run · "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    print(f"\n## map_frame's parts in the {args.engine} run, every frame after 0 (ms per call)\n")
    print("| part | calls | median ms | mean ms | total s |\n|---|---|---|---|---|")
    for label, values in frame_parts.items():
        print(f"| {label} | {len(values)} | {np.median(values) * 1e3:.0f} | {np.mean(values) * 1e3:.0f} | "
              f"{np.sum(values):.1f} |")
    for n_threads in threads:
        torch.set_num_threads(args.torch_threads or n_threads)
        numba.set_num_threads(min(n_threads, numba.config.NUMBA_NUM_THREADS))
        for it in iters:
            runs, stats = replay(call, it, args.repeats)
            print(f"\n## One mapping step of frame {args.frame}: {it} iterations, {n_threads} thread(s), "
                  f"{args.repeats} repeats · {stats}\n")
            print("\n".join(table(runs, it)))


if __name__ == "__main__":
    main()
