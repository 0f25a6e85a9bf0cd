"""CPU backend, sparse pixels: composite only chosen pixels, with a hand-written backward.

`rasterize_cpu_pixels(..., px, py)` returns what `rasterize_cpu` would give at pixels
(px[k], py[k]) — features P x C and alpha P — without rendering the image. It shares the binning
of `cpu.py` (depth sort, per-Gaussian boxes, 16 x 16 tile lists) and evaluates each chosen pixel
against its tile's sorted list with exactly the dense kernel's per-pixel test: the Gaussian's box
contains the pixel, power <= 0, alpha = min(0.99, o exp(power)) >= 1/255, and compositing stops
before the Gaussian that would push transmittance below 1e-4. So the results equal the dense
render at those pixels (tests check it) while the cost follows the number of pixels.

Tracking on one pixel in a few per tile is what makes it cheap (SPLATONIC, HPCA 2026, tracks
SplaTAM on one random pixel per 16 x 16 tile); the projection (torch, gradients to the pose) and
the binning are the same as for a dense render.

The backward walks each pixel's list back to front, recovering T_i = T_{i+1} / (1 - a_i), and
writes one gradient row per (pixel, list position); a serial pass adds the rows into the
Gaussians in a fixed order: deterministic, no atomics. The kernels are plain scalar loops (one
pixel per prange step): with a few thousand pixels they are not where the time goes.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange

from ..parallel import numba_lock
from .cpu import (_C_ALPHA_MAX, _C_ALPHA_MIN, _C_HALF, _C_ONE, _C_T_MIN, _C_ZERO, _P_A, _P_B,
                  _P_C, _P_MX, _P_MY, _P_O, TILE, _bin, _exp, _np, _working_dtype)


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _pixels_forward(params, features, boxes, tile_offsets, isect_gauss, consts, ntx, px, py,
                    out, alpha, t_final, last, contributions):
    amax, amin, tmin = consts[_C_ALPHA_MAX], consts[_C_ALPHA_MIN], consts[_C_T_MIN]
    half, one, zero = consts[_C_HALF], consts[_C_ONE], consts[_C_ZERO]
    C = features.shape[1]
    for p in prange(px.shape[0]):
        x, y = px[p], py[p]
        xf, yf = params.dtype.type(x), params.dtype.type(y)
        t = (y // TILE) * ntx + x // TILE
        T = one
        acc_alpha = zero
        for c in range(C):
            out[p, c] = zero
        lastk = 0
        n = 0
        start = tile_offsets[t]
        for k in range(start, tile_offsets[t + 1]):
            j = isect_gauss[k]
            if x < boxes[j, 0] or x > boxes[j, 1] or y < boxes[j, 2] or y > boxes[j, 3]:
                continue
            dx = params[j, _P_MX] - xf
            dy = params[j, _P_MY] - yf
            power = -half * (params[j, _P_A] * dx * dx + params[j, _P_C] * dy * dy) - params[j, _P_B] * dx * dy
            if power > zero:
                continue
            a = min(amax, params[j, _P_O] * _exp(power))
            if a < amin:
                continue
            tn = T * (one - a)
            if tn < tmin:
                break
            w = a * T
            for c in range(C):
                out[p, c] += features[j, c] * w
            acc_alpha += w
            T = tn
            lastk = k - start + 1
            n += 1
        alpha[p] = acc_alpha
        t_final[p] = T
        last[p] = lastk
        contributions[p] = n


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _pixels_backward(params, features, boxes, tile_offsets, isect_gauss, consts, ntx, px, py,
                     t_final, last, row_offsets, grad_out, grad_alpha, rows, row_gauss):
    """rows[r] = (d means2d (2), d conic (3), d opacity, d features (C)) of one (pixel, contributing
    Gaussian); a pixel's rows start at row_offsets[p]."""
    amax, amin = consts[_C_ALPHA_MAX], consts[_C_ALPHA_MIN]
    half, one, zero = consts[_C_HALF], consts[_C_ONE], consts[_C_ZERO]
    C = features.shape[1]
    for p in prange(px.shape[0]):
        x, y = px[p], py[p]
        xf, yf = params.dtype.type(x), params.dtype.type(y)
        t = (y // TILE) * ntx + x // TILE
        start = tile_offsets[t]
        T = t_final[p]
        gat = grad_alpha[p] * t_final[p]
        S = np.zeros(C, dtype=params.dtype)
        r = row_offsets[p + 1]
        for k in range(start + last[p] - 1, start - 1, -1):
            j = isect_gauss[k]
            if x < boxes[j, 0] or x > boxes[j, 1] or y < boxes[j, 2] or y > boxes[j, 3]:
                continue
            A, B, Cc, o = params[j, _P_A], params[j, _P_B], params[j, _P_C], params[j, _P_O]
            dx = params[j, _P_MX] - xf
            dy = params[j, _P_MY] - yf
            power = -half * (A * dx * dx + Cc * dy * dy) - B * dx * dy
            if power > zero:
                continue
            G = _exp(power)
            a0 = o * G
            clamped = a0 > amax
            a = amax if clamped else a0
            if a < amin:
                continue
            r -= 1
            row_gauss[r] = j
            for q in range(rows.shape[1]):
                rows[r, q] = zero
            inv = one / (one - a)
            T = T * inv                      # transmittance in front of this Gaussian
            w = a * T
            g_a = gat * inv
            for c in range(C):
                g_a += grad_out[p, c] * (T * features[j, c] - S[c] * inv)
                rows[r, 6 + c] = w * grad_out[p, c]
                S[c] += features[j, c] * w
            if not clamped:
                g_pow = g_a * a
                rows[r, 5] = g_a * G
                rows[r, 0] = -g_pow * (A * dx + B * dy)
                rows[r, 1] = -g_pow * (Cc * dy + B * dx)
                rows[r, 2] = -g_pow * half * dx * dx
                rows[r, 3] = -g_pow * dx * dy
                rows[r, 4] = -g_pow * half * dy * dy


@njit(cache=True, nogil=True)
def _add_rows(order, rows, row_gauss, grads):
    """grads[order[j]] += rows of Gaussian j, in row order (serial: deterministic)."""
    for r in range(rows.shape[0]):
        g = order[row_gauss[r]]
        for q in range(rows.shape[1]):
            grads[g, q] += rows[r, q]


def _check_pixels(px: np.ndarray, py: np.ndarray, width: int, height: int) -> None:
    if px.shape != py.shape or px.ndim != 1:
        raise ValueError("pixel x and y must be 1-D arrays of the same length")
    if px.size and (px.min() < 0 or py.min() < 0 or px.max() >= width or py.max() >= height):
        raise ValueError(f"pixels must lie inside the {width} x {height} image")


class _RasterizePixelsCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, depths, radii, width, height, px, py):
        dtype = _working_dtype(means2d)
        with numba_lock():
            b = _bin(means2d, conics, opacities, features, depths, radii, width, height, dtype, {})
            feats = np.ascontiguousarray(np.concatenate(b.blocks, axis=1)[:, :b.nch])   # depth order
            P, C = px.shape[0], feats.shape[1]
            out = np.empty((P, C), dtype=dtype)
            alpha = np.empty(P, dtype=dtype)
            t_final = np.empty(P, dtype=dtype)
            last = np.empty(P, dtype=np.int64)
            contributions = np.empty(P, dtype=np.int64)
            _pixels_forward(b.params, feats, b.boxes, b.tile_offsets, b.isect_gauss, b.consts, b.ntx,
                            px, py, out, alpha, t_final, last, contributions)
        ctx.saved = (b, feats, px, py, t_final, last, contributions)
        ctx.like = (means2d.dtype, means2d.device)
        dt, device = ctx.like
        return torch.from_numpy(out).to(device, dt), torch.from_numpy(alpha).to(device, dt)

    @staticmethod
    def backward(ctx, grad_out, grad_alpha):
        b, feats, px, py, t_final, last, contributions = ctx.saved
        dtype, device = ctx.like
        wd = b.params.dtype
        P, C = px.shape[0], feats.shape[1]
        go = np.zeros((P, C), dtype=wd) if grad_out is None else _np(grad_out, wd)
        ga = np.zeros(P, dtype=wd) if grad_alpha is None else _np(grad_alpha, wd)
        row_offsets = np.zeros(P + 1, dtype=np.int64)
        np.cumsum(contributions, out=row_offsets[1:])
        rows = np.empty((int(row_offsets[-1]), 6 + C), dtype=wd)
        row_gauss = np.empty(int(row_offsets[-1]), dtype=np.int64)
        grads = np.zeros((b.n, 6 + C), dtype=wd)
        with numba_lock():
            _pixels_backward(b.params, feats, b.boxes, b.tile_offsets, b.isect_gauss, b.consts, b.ntx,
                             px, py, t_final, last, row_offsets, go, ga, rows, row_gauss)
            _add_rows(b.order, rows, row_gauss, grads)
        g = torch.from_numpy(grads).to(device, dtype)
        return g[:, 0:2], g[:, 2:5], g[:, 5], g[:, 6:], None, None, None, None, None, None


def rasterize_cpu_pixels(means2d, conics, opacities, features, depths, radii, width, height, px, py):
    """`rasterize_cpu` evaluated at pixels (px[k], py[k]) only (integer arrays, inside the image).

    Returns (P x C features, P alpha); differentiable w.r.t. means2d, conics, opacities, features.
    """
    px = np.ascontiguousarray(np.asarray(px, dtype=np.int64))
    py = np.ascontiguousarray(np.asarray(py, dtype=np.int64))
    _check_pixels(px, py, int(width), int(height))
    return _RasterizePixelsCPU.apply(means2d, conics, opacities, features, depths, radii,
                                     int(width), int(height), px, py)
