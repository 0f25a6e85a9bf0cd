"""Projection speed on the CPU: the torch reference (`project_gaussians_torch`, ~100 small torch ops
and a bmm, autograd) against the fused Numba path (`project_gaussians`, which sends isotropic
Gaussians in CPU tensors to project_cpu.py).

    python benchmarks/project.py [--gaussians 70000] [--repeats 20] [--dtype float32] [--size 640x480]

Inputs: N isotropic Gaussians at random pixels of a W x H pinhole camera (f = 0.9 W), depth
U(0.5, 5) m, radius 1-3 px on screen, opacity U(0.1, 0.9), seen from a pose given as a quaternion
and a translation; means, log_scales, logit_opacities, quaternion and translation require a gradient
(mapping and tracking together). The backward is that of a random linear loss of means2d, conics,
depths and opacities (autograd.grad with random grad_outputs, so no loss ops are timed). Printed
per path, in milliseconds, medians over --repeats runs after two warm-up runs (which also
JIT-compile or load the Numba cache):
  forward           project(...) with autograd on
  forward_backward  project(...), then autograd.grad to the five inputs (through
                    w2c_from_quat_trans, which both paths pay)
and the largest relative differences of the outputs and the gradients between the two paths.
Prints only; writes nothing.
"""

from __future__ import annotations

from splat_core.openmp_env import openmp_defaults  # noqa: E402
openmp_defaults()   # as the CLI, before torch: how idle OpenMP threads wait

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import torch  # noqa: E402

from splat_core.camera import Intrinsics, w2c_from_quat_trans  # noqa: E402
from splat_core.gaussians import Gaussians  # noqa: E402
from splat_core.render.project import project_gaussians, project_gaussians_torch  # noqa: E402

OUTPUTS = ("means2d", "conics", "depths", "opacities")


def make_inputs(n: int, W: int, H: int, dtype, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    rand = lambda *s: torch.rand(*s, generator=gen, dtype=torch.float64)  # noqa: E731
    f = 0.9 * W
    intr = Intrinsics(f, f, W / 2 - 0.5, H / 2 - 0.5, W, H)
    z = 0.5 + 4.5 * rand(n)
    u, v = rand(n) * W, rand(n) * H
    q = torch.tensor([1.0, 0.02, -0.01, 0.015], dtype=dtype)
    t = torch.tensor([0.03, -0.02, 0.05], dtype=dtype)
    p_cam = torch.stack([(u - intr.cx) / f * z, (v - intr.cy) / f * z, z], -1)
    R = w2c_from_quat_trans(q.double(), t.double())[:3, :3]
    means = (p_cam - t.double()) @ R                     # inverse of p_cam = R m + t
    log_scales = torch.log((1 + 2 * rand(n)) * z / f)[:, None]
    o = 0.1 + 0.8 * rand(n)
    logit = torch.log(o) - torch.log1p(-o)
    leaves = [x.to(dtype).contiguous().requires_grad_() for x in (means, log_scales, logit, q, t)]
    weights = {name: torch.randn(*shape, generator=gen, dtype=torch.float64).to(dtype)
               for name, shape in (("means2d", (n, 2)), ("conics", (n, 3)), ("depths", (n,)),
                                   ("opacities", (n,)))}
    return intr, leaves, weights


_UNUSED: dict = {}   # colours and rotations (the projection reads neither), made once


def run(fn, intr, leaves, weights, backward: bool):
    means, log_scales, logit, q, t = leaves
    key = (means.shape[0], means.dtype)
    if key not in _UNUSED:
        _UNUSED[key] = (torch.zeros(means.shape[0], 3, dtype=means.dtype),
                        torch.zeros(means.shape[0], 4, dtype=means.dtype))
    colors, rot = _UNUSED[key]
    p = fn(Gaussians(means, colors, rot, logit, log_scales), intr, w2c_from_quat_trans(q, t))
    if backward:   # the gradients of sum over outputs of (weights * output)
        grads = torch.autograd.grad([getattr(p, name) for name in OUTPUTS], leaves,
                                    grad_outputs=[weights[name] for name in OUTPUTS])
        return p, grads
    return p, None


def timed(fn, intr, leaves, weights, repeats: int, backward: bool) -> float:
    times = []
    for i in range(repeats + 2):
        t0 = time.perf_counter()
        run(fn, intr, leaves, weights, backward)
        if i >= 2:
            times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def rel(a, b) -> float:
    a, b = a.detach().double(), b.detach().double()
    return float((a - b).abs().max()) / max(1.0, float(b.abs().max()))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--gaussians", type=int, default=70000)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--dtype", default="float32", choices=("float32", "float64"))
    ap.add_argument("--size", default="640x480", help="W x H")
    a = ap.parse_args()
    W, H = (int(v) for v in a.size.split("x"))
    dtype = getattr(torch, a.dtype)
    intr, leaves, weights = make_inputs(a.gaussians, W, H, dtype)

    print(f"projection of {a.gaussians} isotropic Gaussians, {a.dtype}, {W} x {H}, "
          f"torch threads {torch.get_num_threads()}, median of {a.repeats} runs (ms)")
    for name, fn in (("torch", project_gaussians_torch), ("fused", project_gaussians)):
        fwd = timed(fn, intr, leaves, weights, a.repeats, backward=False)
        fb = timed(fn, intr, leaves, weights, a.repeats, backward=True)
        print(f"  {name:6s} forward {fwd:7.2f}   forward_backward {fb:7.2f}")

    p_ref, g_ref = run(project_gaussians_torch, intr, leaves, weights, True)
    p_got, g_got = run(project_gaussians, intr, leaves, weights, True)
    outs = "  ".join(f"{n} {rel(getattr(p_got, n), getattr(p_ref, n)):.1e}" for n in OUTPUTS)
    grads = "  ".join(f"{n} {rel(x, y):.1e}" for n, x, y in
                      zip(("means", "log_scales", "logit", "q", "t"), g_got, g_ref))
    print(f"  max relative difference: {outs}")
    print(f"  gradients:               {grads}")
    print(f"  radii differing: {int((p_got.radii != p_ref.radii).sum())} of {a.gaussians}")


if __name__ == "__main__":
    main()
