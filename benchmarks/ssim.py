"""SSIM speed on the CPU: the torch reference (`losses.ssim_map(...).mean()`, F.conv2d and
autograd) against the Numba path (`losses.ssim`, which dispatches CPU tensors to ssim_cpu.py).

    python benchmarks/ssim.py [--size 320x240] [--repeats 20] [--dtype float32]

Inputs: a random H x W x 3 "rendered" image x that requires a gradient and a constant target
y = clip(x + 0.1 N(0, 1), 0, 1), as the mapping loss calls it (1 - ssim(rendered, observed)).
Printed per path, in milliseconds, medians over --repeats runs after two warm-up runs (which also
JIT-compile or load the Numba cache):
  forward           ssim(x, y) with autograd on (what a training step's forward pays)
  forward_backward  ssim(x, y).backward()
and the largest differences of the value and of the gradient between the two paths.
Prints only; writes nothing.
"""

from __future__ import annotations

from splat_core.openmp_env import openmp_defaults  # noqa: E402
openmp_defaults()   # as the CLI, before torch: how idle OpenMP threads wait

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import torch  # noqa: E402

from splat_core.losses import ssim, ssim_map  # noqa: E402


def torch_ssim(x, y):
    return ssim_map(x, y).mean()


def timed(fn, x, y, repeats: int, backward: bool) -> float:
    times = []
    for i in range(repeats + 2):
        x.grad = None
        t0 = time.perf_counter()
        v = fn(x, y)
        if backward:
            v.backward()
        t = time.perf_counter() - t0
        if i >= 2:
            times.append(t)
    return 1e3 * statistics.median(times)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="320x240", help="W x H")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--dtype", default="float32", choices=("float32", "float64"))
    a = ap.parse_args()
    W, H = (int(v) for v in a.size.split("x"))
    dtype = getattr(torch, a.dtype)
    g = torch.Generator().manual_seed(0)
    x = torch.rand(H, W, 3, generator=g, dtype=dtype).requires_grad_(True)
    y = (x.detach() + 0.1 * torch.randn(H, W, 3, generator=g, dtype=dtype)).clamp(0, 1)

    print(f"SSIM {H} x {W} x 3 {a.dtype}, torch threads {torch.get_num_threads()}, "
          f"median of {a.repeats} runs (ms)")
    for name, fn in (("torch", torch_ssim), ("numba", ssim)):
        fwd = timed(fn, x, y, a.repeats, backward=False)
        fb = timed(fn, x, y, a.repeats, backward=True)
        print(f"  {name:6s} forward {fwd:7.2f}   forward_backward {fb:7.2f}")

    x.grad = None
    ref = torch_ssim(x, y)
    ref.backward()
    g_ref = x.grad.clone()
    x.grad = None
    got = ssim(x, y)
    got.backward()
    print(f"  |value diff| {abs(float(got.detach()) - float(ref.detach())):.2e}   "
          f"max |grad diff| {float((x.grad - g_ref).abs().max()):.2e} "
          f"(max |grad| {float(g_ref.abs().max()):.2e})")


if __name__ == "__main__":
    main()
