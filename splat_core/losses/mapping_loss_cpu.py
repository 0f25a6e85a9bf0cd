"""The mapping loss (`mapping.mapping_loss`) for CPU tensors as one autograd step.

The loss is a dozen elementwise torch operations around SSIM; on a 320 x 240 image each is a few
tens of microseconds, and their autograd graph costs as much again in the backward: about 6 ms
for forward + backward against 2 ms for SSIM alone (a mapping iteration is ~50 ms). Here one
Numba pass over the pixels sums the L1 terms, keeps the signs of their residuals (their
gradients up to a constant) and builds SSIM's input; SSIM runs its Numba kernels directly
(`ssim_cpu.ssim_np`); the backward is SSIM's backward and one more pass that combines.

Same value and gradient as the torch definition (`mapping._mapping_loss_torch`, the reference:
tests/test_engine.py compares them), including torch's convention that |x| has gradient 0 at 0.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange

from ..parallel import numba_lock
from .ssim_cpu import ssim_grad_np, ssim_np


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _l1_terms(c, d, oc, od, pix, sums, sign_c, sign_d, mixed):
    """Per row: sums[y] = (sum |depth residual| over valid pixels, valid pixels, sum |colour
    residual| over drawn pixels, drawn pixels); sign_c / sign_d: the residuals' signs where they
    count (0 elsewhere); mixed: the rendered colour where drawn, the observed one elsewhere."""
    H, W = d.shape
    zero = c[0, 0, 0] * 0
    for y in prange(H):
        s_d = 0.0
        n_v = 0.0
        s_c = 0.0
        n_d = 0.0
        for x in range(W):
            p = pix[y, x]
            r = od[y, x] - d[y, x]
            v = p and od[y, x] > 0
            sign_d[y, x] = (np.sign(r) if v else zero)
            if v:
                s_d += abs(r)
                n_v += 1.0
            if p:
                n_d += 1.0
            for k in range(3):
                rc = oc[y, x, k] - c[y, x, k]
                sign_c[y, x, k] = np.sign(rc) if p else zero
                mixed[y, x, k] = c[y, x, k] if p else oc[y, x, k]
                if p:
                    s_c += abs(rc)
        sums[y, 0] = s_d
        sums[y, 1] = n_v
        sums[y, 2] = s_c
        sums[y, 3] = n_d


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _combine(sign_c, g_ssim, pix, k_c, grad_c):
    """grad_c = k_c sign_c + g_ssim on drawn pixels (0 elsewhere)."""
    H, W = pix.shape
    zero = k_c * 0
    for y in prange(H):
        for x in range(W):
            p = pix[y, x]
            for k in range(3):
                grad_c[y, x, k] = k_c * sign_c[y, x, k] + g_ssim[y, x, k] if p else zero


class _MappingLossCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, color, depth, obs_color, obs_depth, pixels, depth_weight, color_weight, ssim_weight):
        c, d = color.detach().numpy(), depth.detach().numpy()
        oc, od = obs_color.numpy(), obs_depth.numpy()
        H, W = d.shape
        dt = c.dtype.type
        pix = np.ones((H, W), dtype=np.bool_) if pixels is None else pixels.numpy()
        sums = np.empty((H, 4))
        sign_c, sign_d, mixed = np.empty_like(c), np.empty_like(d), np.empty_like(c)
        with numba_lock():
            _l1_terms(c, d, oc, od, pix, sums, sign_c, sign_d, mixed)
        s_d, n_valid, s_c, drawn = sums.sum(axis=0)
        n_valid, drawn = max(n_valid, 1.0), max(drawn, 1.0)
        s, partials = ssim_np(mixed, oc, True)
        scale = H * W / drawn                    # SSIM over the drawn share (1 without pixels)
        loss = (depth_weight * s_d / n_valid
                + color_weight * ((1 - ssim_weight) * s_c / (3 * drawn) + ssim_weight * (1 - s) * scale))
        ctx.saved = (mixed, oc, partials, sign_c, sign_d, pix)
        ctx.k = (-depth_weight / n_valid, -color_weight * (1 - ssim_weight) / (3 * drawn),
                 -color_weight * ssim_weight * scale, dt)
        return torch.tensor(loss, dtype=color.dtype)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_out):
        mixed, oc, partials, sign_c, sign_d, pix = ctx.saved
        k_d, k_c, k_s, dt = ctx.k
        g = float(grad_out)
        g_ssim = ssim_grad_np(mixed, oc, partials, k_s * g)
        grad_c = np.empty_like(sign_c)
        with numba_lock():
            _combine(sign_c, g_ssim, pix, dt(k_c * g), grad_c)
        return (torch.from_numpy(grad_c), torch.from_numpy(sign_d * dt(k_d * g)),
                None, None, None, None, None, None)


def mapping_loss_cpu(color, depth, obs_color, obs_depth, pixels, depth_weight: float, color_weight: float,
                     ssim_weight: float) -> torch.Tensor:
    """The mapping loss of rendered (color H x W x 3, depth H x W) against the observation; pixels:
    None or an H x W bool mask (the drawn tiles). CPU tensors of one float dtype."""
    return _MappingLossCPU.apply(color, depth, obs_color.detach(), obs_depth.detach(), pixels,
                                 float(depth_weight), float(color_weight), float(ssim_weight))
