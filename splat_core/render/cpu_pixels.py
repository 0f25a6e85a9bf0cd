"""CPU backend, sparse pixels: composite only chosen pixels, with a hand-written backward.

`rasterize_cpu_pixels(..., px, py)` returns what `rasterize_cpu` would give at pixels
(px[k], py[k]) — features P x C and alpha P — without rendering the image. It shares the dense
path's per-Gaussian boxes and depth sort (`cpu.py`), but bins to the chosen pixels themselves: a
summed-area table of the chosen pixels counts those inside each Gaussian's box in four reads; only
Gaussians with one or more are depth-sorted, and a counting sort of their (Gaussian, pixel) pairs
gives every pixel the list of Gaussians whose box holds it, front to back. Each pixel evaluates
exactly its list with the dense kernel's per-pixel test (power <= 0, alpha = min(0.99, o exp(power))
>= 1/255, compositing stops before the Gaussian that would push transmittance below 1e-4): the
same Gaussians in the same order as the dense render's tile list after its box test, so the results
equal the dense render at those pixels (to rounding: the dense kernels fuse multiply-adds; tests
check it) while the cost follows the pixels. (Until 2026-12-07 each pixel walked its whole 16 x 16
tile's list, box-testing every entry, and every Gaussian in view was sorted and binned to tiles:
with the tracker's one pixel in 64, the forward took 1.3-1.4x and the backward 1.7x as long, for
the same results bit for bit: `benchmarks/rasterizer_ab.py --pixels`; docs/benchmarks.md,
"Renderer".)

Tracking on one pixel in a few per tile is what makes it cheap (SPLATONIC, HPCA 2026, tracks
SplaTAM on one random pixel per 16 x 16 tile); the projection (torch, gradients to the pose) is
the same as for a dense render.

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
                  _P_C, _P_MX, _P_MY, _P_O, _P_WIDTH, TILE, _consts, _exp, _gather_sorted, _np,
                  _prepare_gaussians, _working_dtype, depth_order, tile_table)


@njit(cache=True, nogil=True)
def _pixel_counts(px, py, width, height):
    """Summed-area table of the chosen pixels: sat[y, x] = how many lie in [0, x) x [0, y)."""
    sat = np.zeros((height + 1, width + 1), dtype=np.int64)
    for p in range(px.shape[0]):
        sat[py[p] + 1, px[p] + 1] += 1
    for y in range(1, height + 1):
        for x in range(1, width + 1):
            sat[y, x] += sat[y, x - 1] + sat[y - 1, x] - sat[y - 1, x - 1]
    return sat


@njit(parallel=True, cache=True, nogil=True)
def _count_hits(boxes, drawn, sat, hits):
    """hits[j]: the chosen pixels inside Gaussian j's box (0 where it has no box)."""
    for j in prange(boxes.shape[0]):
        n = 0
        if drawn[j]:
            x0, x1, y0, y1 = boxes[j, 0], boxes[j, 1] + 1, boxes[j, 2], boxes[j, 3] + 1
            n = sat[y1, x1] - sat[y0, x1] - sat[y1, x0] + sat[y0, x0]
        hits[j] = n


@njit(parallel=True, cache=True, nogil=True)
def _pair_pixels(boxes, pair_offsets, sat, by_row, pair_pix):
    """pair_pix[pair_offsets[j]:pair_offsets[j + 1]]: the chosen pixels in Gaussian j's box, row by
    row. by_row: the pixel indices ordered by (y, x), so a row's pixels in [x0, x1] are one run of it,
    found from the summed-area table (pixels in row y left of x: sat[y + 1, x] - sat[y, x])."""
    W = sat.shape[1] - 1
    for j in prange(boxes.shape[0]):
        m = pair_offsets[j]
        x0, x1, y0, y1 = boxes[j, 0], boxes[j, 1] + 1, boxes[j, 2], boxes[j, 3]
        for y in range(y0, y1 + 1):
            left = sat[y + 1, x0] - sat[y, x0]
            n = sat[y + 1, x1] - sat[y, x1] - left
            start = sat[y, W] + left
            for k in range(start, start + n):
                pair_pix[m] = by_row[k]
                m += 1


@njit(cache=True, nogil=True)
def _bin_to_pixels(pair_offsets, pair_pix, P):
    """Counting sort of the (Gaussian, pixel) pairs by pixel, Gaussians in their (depth) order
    within a pixel: pix_offsets (P + 1) and pix_gauss."""
    pix_offsets = np.zeros(P + 1, dtype=np.int64)
    for m in range(pair_pix.shape[0]):
        pix_offsets[pair_pix[m] + 1] += 1
    for p in range(P):
        pix_offsets[p + 1] += pix_offsets[p]
    cursor = pix_offsets[:-1].copy()
    pix_gauss = np.empty(pair_pix.shape[0], dtype=np.int32)
    for j in range(pair_offsets.shape[0] - 1):
        for m in range(pair_offsets[j], pair_offsets[j + 1]):
            p = pair_pix[m]
            pix_gauss[cursor[p]] = j
            cursor[p] += 1
    return pix_offsets, pix_gauss


class _PixelBins:
    """The binning of one sparse render (what its backward needs too)."""

    __slots__ = ("n", "consts", "order", "params", "feats", "pix_offsets", "pix_gauss")


def _bin_pixels(means2d, conics, opacities, features, depths, radii, width, height, dtype, px, py):
    """Boxes, depth order and per-pixel lists of the Gaussians whose box contains a chosen pixel."""
    b = _PixelBins()
    b.n = means2d.shape[0]
    b.consts = _consts(dtype, width, height)
    ntx, nty = -(-width // TILE), -(-height // TILE)
    tiles = np.zeros(ntx * nty, dtype=np.uint8)
    tiles[(py // TILE) * ntx + px // TILE] = 1
    live = np.flatnonzero(radii.detach().cpu().numpy() > 0)
    params = np.empty((live.shape[0], _P_WIDTH), dtype=dtype)
    boxes = np.empty((live.shape[0], 4), dtype=np.int64)
    drawn = np.empty(live.shape[0], dtype=np.bool_)
    _prepare_gaussians(live, _np(means2d, dtype), _np(conics, dtype), _np(opacities, dtype),
                       width, height, b.consts, tile_table(tiles, ntx, nty), params, boxes, drawn)
    sat = _pixel_counts(px, py, width, height)
    hits = np.empty(live.shape[0], dtype=np.int64)
    _count_hits(boxes, drawn, sat, hits)
    kept = np.flatnonzero(hits)
    pick = kept[depth_order(depths.detach().cpu().numpy()[live[kept]])]   # positions in `live`, front to back
    L = pick.shape[0]
    feats = _np(features, dtype)
    b.order, b.params, sorted_boxes = np.empty(L, np.int64), np.empty((L, _P_WIDTH), dtype), np.empty((L, 4), np.int64)
    blocks = np.empty((-(-feats.shape[1] // 4), L, 4), dtype)     # the dense path's gather: 4-channel blocks
    _gather_sorted(pick, live, params, boxes, feats, b.order, b.params, sorted_boxes, blocks)
    b.feats = blocks[0] if feats.shape[1] == 4 else \
        np.ascontiguousarray(np.concatenate(list(blocks), axis=1)[:, :feats.shape[1]])
    pair_offsets = np.zeros(L + 1, dtype=np.int64)
    np.cumsum(hits[pick], out=pair_offsets[1:])
    pair_pix = np.empty(int(pair_offsets[L]), dtype=np.int64)
    _pair_pixels(sorted_boxes, pair_offsets, sat, np.argsort(py * width + px, kind="stable"), pair_pix)
    b.pix_offsets, b.pix_gauss = _bin_to_pixels(pair_offsets, pair_pix, px.shape[0])
    return b


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _pixels_forward(params, features, pix_offsets, pix_gauss, consts, px, py,
                    out, alpha, t_final, last, contributions):
    amax, amin, tmin = consts[_C_ALPHA_MAX], consts[_C_ALPHA_MIN], consts[_C_T_MIN]
    half, one, zero = consts[_C_HALF], consts[_C_ONE], consts[_C_ZERO]
    C = features.shape[1]
    for p in prange(px.shape[0]):
        xf, yf = params.dtype.type(px[p]), params.dtype.type(py[p])
        T = one
        acc_alpha = zero
        for c in range(C):
            out[p, c] = zero
        lastk = 0
        n = 0
        start = pix_offsets[p]
        for k in range(start, pix_offsets[p + 1]):
            j = pix_gauss[k]
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
def _pixels_backward(params, features, pix_offsets, pix_gauss, consts, px, py,
                     t_final, last, row_offsets, grad_out, grad_alpha, rows, row_gauss):
    """rows[r] = (d means2d (2), d conic (3), d opacity, d features (C)) of one (pixel, contributing
    Gaussian); a pixel's rows start at row_offsets[p]."""
    amax, amin = consts[_C_ALPHA_MAX], consts[_C_ALPHA_MIN]
    half, one, zero = consts[_C_HALF], consts[_C_ONE], consts[_C_ZERO]
    C = features.shape[1]
    for p in prange(px.shape[0]):
        xf, yf = params.dtype.type(px[p]), params.dtype.type(py[p])
        start = pix_offsets[p]
        T = t_final[p]
        gat = grad_alpha[p] * t_final[p]
        S = np.zeros(C, dtype=params.dtype)
        r = row_offsets[p + 1]
        for k in range(start + last[p] - 1, start - 1, -1):
            j = pix_gauss[k]
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
            b = _bin_pixels(means2d, conics, opacities, features, depths, radii, width, height, dtype, px, py)
            P, C = px.shape[0], b.feats.shape[1]
            out = np.empty((P, C), dtype=dtype)
            alpha = np.empty(P, dtype=dtype)
            t_final = np.empty(P, dtype=dtype)
            last = np.empty(P, dtype=np.int64)
            contributions = np.empty(P, dtype=np.int64)
            _pixels_forward(b.params, b.feats, b.pix_offsets, b.pix_gauss, b.consts, px, py,
                            out, alpha, t_final, last, contributions)
        ctx.saved = (b, px, py, t_final, last, contributions)
        ctx.like = (means2d.dtype, means2d.device)
        dt, device = ctx.like
        return torch.from_numpy(out).to(device, dt), torch.from_numpy(alpha).to(device, dt)

    @staticmethod
    def backward(ctx, grad_out, grad_alpha):
        b, px, py, t_final, last, contributions = ctx.saved
        dtype, device = ctx.like
        wd = b.params.dtype
        P, C = px.shape[0], b.feats.shape[1]
        go = np.zeros((P, C), dtype=wd) if grad_out is None else _np(grad_out, wd)
        ga = np.zeros(P, dtype=wd) if grad_alpha is None else _np(grad_alpha, wd)
        row_offsets = np.zeros(P + 1, dtype=np.int64)
        np.cumsum(contributions, out=row_offsets[1:])
        rows = np.empty((int(row_offsets[-1]), 6 + C), dtype=wd)
        row_gauss = np.empty(int(row_offsets[-1]), dtype=np.int64)
        grads = np.zeros((b.n, 6 + C), dtype=wd)
        with numba_lock():
            _pixels_backward(b.params, b.feats, b.pix_offsets, b.pix_gauss, b.consts, px, py,
                             t_final, last, row_offsets, go, ga, rows, row_gauss)
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
