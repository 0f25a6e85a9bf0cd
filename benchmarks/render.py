"""Renderer speed: forward and forward+backward milliseconds per backend, size and map size.

    python benchmarks/render.py [--json] [--repeats N] [--backends cpu,cuda]
                                [--sizes 320x240,640x480] [--gaussians 50000,200000]

Scene: SplaTAM's initialisation on a synthetic room. A depth map of a box-shaped room (walls,
floor and ceiling at 1-5 m, two boxes standing in it) is back-projected at random pixels; each
point becomes an isotropic Gaussian of radius depth / f * U(1, 3) (1-3 px on screen), opacity 0.5
(logit 0, as SplaTAM initialises), random colour. The camera looks at the room from its origin.

forward_ms          render(...) with autograd off (projection + rasterisation)
forward_backward_ms render(...) with gradients on every Gaussian parameter and the pose,
                    a loss (L1 on colour and depth, plus alpha), loss.backward()
Both are medians over --repeats runs after one warm-up run (which also JIT-compiles or loads
the Numba cache). peak_mem_mb is the process's maximum resident set size
(resource.getrusage ru_maxrss) after that configuration, i.e. a high-water mark over the run so
far; for CUDA, torch.cuda.max_memory_allocated is reported as peak_gpu_mem_mb.
"""

from __future__ import annotations

from splat_core.openmp_env import openmp_defaults  # noqa: E402
openmp_defaults()   # as the CLI, before torch: how idle OpenMP threads wait

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402
from splat_core.camera import Intrinsics, w2c_from_quat_trans  # noqa: E402
from splat_core.gaussians import Gaussians  # noqa: E402
from splat_core.render import render, resolve_backend  # noqa: E402


def room_depth(intr: Intrinsics) -> np.ndarray:
    """Depth (metres) of a box room seen from its origin: ray-cast against planes and boxes."""
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float64), np.arange(intr.height, dtype=np.float64))
    dx = (u - intr.cx) / intr.fx            # ray direction (dx, dy, 1): the hit's z is its parameter
    dy = (v - intr.cy) / intr.fy
    depth = np.full(u.shape, np.inf)

    def plane(coord_dir, value):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = value / coord_dir
        return np.where((t > 0) & np.isfinite(t), t, np.inf)

    depth = np.minimum(depth, np.full(u.shape, 5.0))            # back wall
    depth = np.minimum(depth, plane(dx, -2.2))                  # left wall
    depth = np.minimum(depth, plane(dx, 2.0))                   # right wall
    depth = np.minimum(depth, plane(dy, 1.3))                   # floor (+y is down)
    depth = np.minimum(depth, plane(dy, -1.5))                  # ceiling
    for lo, hi in (((-1.4, 0.5, 2.0), (-0.6, 1.3, 2.8)), ((0.4, 0.1, 3.0), (1.5, 1.3, 3.8))):
        d = np.stack([dx, dy, np.ones_like(dx)])               # slab test against an axis box
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (np.array(lo)[:, None, None]) / d
            t1 = (np.array(hi)[:, None, None]) / d
        tmin = np.nanmax(np.minimum(t0, t1), axis=0)
        tmax = np.nanmin(np.maximum(t0, t1), axis=0)
        hit = (tmax >= tmin) & (tmin > 0)
        depth = np.where(hit, np.minimum(depth, tmin), depth)
    return np.clip(depth, 1.0, 5.0)


def room_gaussians(intr: Intrinsics, n: int, seed: int = 0, dtype=torch.float32) -> Gaussians:
    rng = np.random.default_rng(seed)
    depth = room_depth(intr)
    pix = rng.integers(0, intr.width * intr.height, size=n)
    v, u = np.divmod(pix, intr.width)
    u = u + rng.uniform(-0.5, 0.5, n)
    v = v + rng.uniform(-0.5, 0.5, n)
    z = depth[v.round().clip(0, intr.height - 1).astype(int), u.round().clip(0, intr.width - 1).astype(int)]
    pts = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], axis=-1)
    radius = z / intr.mean_focal * rng.uniform(1.0, 3.0, n)
    t = lambda a: torch.as_tensor(a, dtype=dtype)  # noqa: E731
    rot = np.zeros((n, 4))
    rot[:, 0] = 1
    return Gaussians(means=t(pts), colors=t(rng.uniform(0, 1, (n, 3))), rotations=t(rot),
                     logit_opacities=t(np.zeros(n)), log_scales=t(np.log(radius)[:, None]))


def _sync(device):
    if device.type == "cuda":
        torch.cuda.synchronize()


def bench_one(backend: str, width: int, height: int, n: int, repeats: int) -> dict:
    device = torch.device("cuda" if backend == "cuda" else "cpu")
    f = 0.9 * width                                   # ~58 degree horizontal field of view
    intr = Intrinsics(f, f, (width - 1) / 2, (height - 1) / 2, width, height)
    g0 = room_gaussians(intr, n)
    g0 = Gaussians(*(x.to(device) for x in (g0.means, g0.colors, g0.rotations,
                                            g0.logit_opacities, g0.log_scales)))
    target_color = torch.rand(height, width, 3, device=device)
    target_depth = torch.rand(height, width, device=device) * 4 + 1
    quat = torch.tensor([1.0, 0.0, 0.0, 0.0], device=device)
    trans = torch.zeros(3, device=device)

    def forward():
        with torch.no_grad():
            r = render(g0, intr, w2c_from_quat_trans(quat, trans), backend=backend)
        _sync(device)
        return r

    def forward_backward():
        params = [x.detach().requires_grad_() for x in (g0.means, g0.colors, g0.rotations,
                                                          g0.logit_opacities, g0.log_scales)]
        q = quat.detach().requires_grad_()
        t = trans.detach().requires_grad_()
        r = render(Gaussians(*params), intr, w2c_from_quat_trans(q, t), backend=backend)
        loss = ((r.color - target_color).abs().sum() + (r.depth - target_depth).abs().sum()
                + r.alpha.sum())
        loss.backward()
        _sync(device)

    def timed(fn):
        fn()                                          # warm-up (JIT compile / cache load)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(1e3 * (time.perf_counter() - t0))
        return statistics.median(times), times

    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats()
    fwd, fwd_all = timed(forward)
    phases = {}
    if backend == "cpu":
        from splat_core.render import cpu
        phases = {k: round(v, 2) for k, v in cpu.last_stats.items() if k.endswith("_ms")}
    fb, fb_all = timed(forward_backward)
    intersections = None
    if backend == "cpu":
        from splat_core.render import cpu
        intersections = cpu.last_stats.get("intersections")
        phases.update({k: round(v, 2) for k, v in cpu.last_stats.items()
                       if k in ("backward_kernel_ms", "reduce_ms")})
    out = {
        "backend": backend, "width": width, "height": height, "gaussians": n,
        "forward_ms": round(fwd, 2), "forward_backward_ms": round(fb, 2),
        "forward_ms_all": [round(x, 1) for x in fwd_all],
        "forward_backward_ms_all": [round(x, 1) for x in fb_all],
        "intersections": intersections,
        "peak_mem_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
        "peak_mem_kind": "ru_maxrss (process high-water mark so far)",
        "phases_last_run_ms": phases,
    }
    if device.type == "cuda":
        out["peak_gpu_mem_mb"] = round(torch.cuda.max_memory_allocated() / 2**20, 1)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true", help="print a JSON list instead of a table")
    ap.add_argument("--repeats", type=int, default=7, help="timed runs per measurement (>= 1)")
    ap.add_argument("--backends", default="cpu,cuda", help="comma list; unavailable ones are skipped")
    ap.add_argument("--sizes", default="320x240,640x480", help="comma list of WxH")
    ap.add_argument("--gaussians", default="50000,200000", help="comma list of map sizes")
    args = ap.parse_args(argv)

    sizes = [tuple(int(x) for x in s.lower().split("x")) for s in args.sizes.split(",") if s]
    counts = [int(x) for x in args.gaussians.split(",") if x]
    info = machine()
    results, skipped = [], []
    for backend in [b.strip() for b in args.backends.split(",") if b.strip()]:
        if backend == "cuda":
            from splat_core.render import cuda
            if not cuda.available():
                skipped.append("cuda (no CUDA device or gsplat not importable)")
                continue
        else:
            resolve_backend(backend, torch.device("cpu"))
        for (w, h) in sizes:
            for n in counts:
                r = bench_one(backend, w, h, n, max(1, args.repeats))
                r["machine"] = info
                results.append(r)
                if not args.json:
                    print(f"{backend:5s} {w:4d}x{h:<4d} {n:7d} gaussians  forward {r['forward_ms']:8.1f} ms"
                          f"  fwd+bwd {r['forward_backward_ms']:8.1f} ms  intersections "
                          f"{r['intersections']}  peak RSS {r['peak_mem_mb']} MB", flush=True)
                    if r["phases_last_run_ms"]:
                        print("      phases (ms, last run): " + ", ".join(
                            f"{k}={v}" for k, v in r["phases_last_run_ms"].items()), flush=True)
    if args.json:
        print(json.dumps(results, indent=1))
        for s in skipped:
            print(f"skipped: {s}", file=sys.stderr)
    else:
        print(f"machine: {info}")
        for s in skipped:
            print(f"skipped: {s}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
