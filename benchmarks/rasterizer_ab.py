"""The CPU rasterizer's forward and backward against another checkout's, paired, on a real map.

    python benchmarks/mapper_profile.py --input ../shared/data/7scenes_redkitchen_300 --frame 100 --save map100.pt
    OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 python benchmarks/rasterizer_ab.py --load map100.pt --before ../before

Loads the other checkout's `splat_core/render/cpu.py` beside this one's (as a second module in this
checkout's package, so both use the same projection and constants), then renders the saved
mapping window's views on random half-tile grids, as mapping does: per view and repeat, both
rasterizers' forward and backward on the same inputs, in alternating order, their outputs asserted
bit for bit equal (`--no-check` for a change that is not meant to keep them). Prints the medians
(ms) and the median of the paired ratios (this over before) with its quartiles: on a loaded
machine pairs taken moments apart share its load, where separate runs do not. `--clock cpu`
(default): the process's CPU time (one thread: OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1).

`--pixels`: the sparse-pixel rasterizer (`cpu_pixels.py`) instead, as the tracker calls it: the map
culled to each view as the tracker culls it, one random pixel per 8 x 8 block (`tracking.pixels:
random`), forward and backward of a random loss. The other checkout's cpu_pixels.py runs on this
checkout's cpu.py (what it imports relatively), so the ratio is that of the sparse path's own code.

Both modules compile into a temporary Numba cache (NUMBA_CACHE_DIR): the other checkout's module,
loaded under another name, would otherwise leave cache entries its own runs cannot load.
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import os
import sys
import tempfile
import time
from pathlib import Path

from splat_core.openmp_env import openmp_defaults  # noqa: E402
openmp_defaults()   # as the CLI, before torch: how idle OpenMP threads wait
os.environ.setdefault("NUMBA_CACHE_DIR", tempfile.mkdtemp(prefix="rasterizer_ab_"))   # before numba

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, machine_line  # noqa: E402

sys.path.insert(0, str(ROOT))


def load_before(checkout: str, name: str = "cpu"):
    """The other checkout's render/NAME.py as splat_core.render._before_NAME (relative imports: this package)."""
    spec = importlib.util.spec_from_file_location(f"splat_core.render._before_{name}",
                                                  Path(checkout) / "splat_core" / "render" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--load", required=True, help="a mapping step saved by mapper_profile.py --save")
    p.add_argument("--before", required=True, help="the other checkout")
    p.add_argument("--views", type=int, default=8)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--clock", choices=("cpu", "wall"), default="cpu")
    p.add_argument("--no-check", action="store_true")
    p.add_argument("--pixels", action="store_true", help="the sparse-pixel rasterizer, as the tracker calls it")
    args = p.parse_args()
    import torch

    import splat_core.render  # noqa: F401  (the package the other module joins)
    from splat_core.device import to_device
    from splat_core.mapping import draw_tiles
    from splat_core.render import cpu
    from splat_core.render.project import project_gaussians

    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    m, window, intr, config, _, _, rng, renderer = torch.load(args.load, weights_only=False)
    rng = copy.deepcopy(rng)
    g = m.tensors(detach=True)
    times = {"this": {"forward": [], "backward": []}, "before": {"forward": [], "backward": []}}
    noise = np.random.default_rng(0)
    load = os.getloadavg()[0]
    if args.pixels:
        from splat_core.pixel_selection import choose_pixels
        from splat_core.render import cpu_pixels
        modules = {"this": cpu_pixels, "before": load_before(args.before, "cpu_pixels")}
    else:
        modules = {"this": cpu, "before": load_before(args.before)}
    for v in range(args.views):
        w2c = to_device(window[v % len(window)].w2c, g.means.dtype, g.means.device)
        if args.pixels:
            view = renderer.visible(g, intr, window[v % len(window)].w2c, margin=0.25)   # as Tracker.nearby
            H, W = intr.height, intr.width
            pixels = choose_pixels("random", np.zeros((H, W, 3), np.float32), np.ones((H, W), np.float32), 8, 1,
                                   noise)
            q = project_gaussians(view, intr, w2c, near=renderer.near)
            features = torch.cat([view.colors, q.depths[:, None]], dim=1)
            grads_out = [torch.as_tensor(noise.standard_normal((len(pixels), 4)).astype(np.float32)),
                         torch.as_tensor(noise.standard_normal(len(pixels)).astype(np.float32))]
        else:
            tiles, _ = draw_tiles(intr, config.tile_fraction, rng, config.min_tiles)
            q = project_gaussians(g, intr, w2c, near=renderer.near)
            features = torch.cat([g.colors, q.depths[:, None]], dim=1)
            grad_image = noise.standard_normal((intr.height, intr.width, 4)).astype(np.float32)
            grad_alpha = noise.standard_normal((intr.height, intr.width)).astype(np.float32)
        for r in range(args.repeats + 1):            # the first pair warms up
            order = ["this", "before"] if r % 2 else ["before", "this"]
            outputs = {}
            for name in order:
                module = modules[name]
                if args.pixels:
                    leaves = [x.detach().requires_grad_() for x in (q.means2d, q.conics, q.opacities, features)]
                    start = clock()
                    out = module.rasterize_cpu_pixels(*leaves, q.depths, q.radii, intr.width, intr.height,
                                                      pixels[:, 0], pixels[:, 1])
                    middle = clock()
                    torch.autograd.backward(out, grads_out)
                    end = clock()
                    outputs[name] = [o.detach().numpy() for o in out] + [x.grad.numpy() for x in leaves]
                else:
                    start = clock()
                    image, alpha, binned = module._forward(q.means2d, q.conics, q.opacities, features, q.depths,
                                                           q.radii, intr.width, intr.height, tiles)
                    middle = clock()
                    grads = module._backward(binned, grad_image, grad_alpha)
                    end = clock()
                    outputs[name] = (image, alpha, *grads)
                if r:
                    times[name]["forward"].append(middle - start)
                    times[name]["backward"].append(end - middle)
            if not args.no_check:
                assert all(np.array_equal(a, b) for a, b in zip(outputs["this"], outputs["before"])), \
                    "outputs differ from the other checkout's"
    what = "sparse pixels" if args.pixels else "dense, mapping tiles"
    print(f"# {Path(args.load).name} · {what} · before: {args.before} · {machine_line()} · {args.clock} clock · "
          f"load {load:.2f} -> {os.getloadavg()[0]:.2f} · {args.views} views x {args.repeats} pairs · "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    print("| part | this (ms, median) | before (ms, median) | paired ratio this / before (median) | quartiles |")
    print("|---|---|---|---|---|")
    for part in ("forward", "backward"):
        a, b = np.array(times["this"][part]), np.array(times["before"][part])
        ratio = a / b
        lo, hi = np.percentile(ratio, [25, 75])
        print(f"| {part} | {np.median(a) * 1e3:.2f} | {np.median(b) * 1e3:.2f} | {np.median(ratio):.3f} | "
              f"{lo:.3f}-{hi:.3f} |")


if __name__ == "__main__":
    main()
