"""CPU backend: a Numba tile rasterizer with a hand-written backward.

`rasterize_cpu` has the signature and the semantics of `reference.rasterize_reference` (the
oracle): Gaussians with radius 0 are culled, the rest are composited front to back in a stable
depth order, pixel (u, v) is evaluated at (u, v), alpha = min(0.99, o exp(power)), contributions
with power > 0 or alpha < 1/255 are skipped, and compositing stops before the Gaussian that
would push transmittance below 1e-4.

How it is fast (what was tried and measured: docs/renderer.md):
- Binning: a Gaussian can only pass the 1/255 test where q(d) = d^T conic d <= K,
  K = 2 ln(255 o). The bounding box of that ellipse (K slightly enlarged) picks the 16 x 16 tiles
  it touches; a counting sort over the depth-sorted Gaussians gives every tile its list of
  Gaussians already in front-to-back order (ties by index: the sort is stable).
- Forward, one tile per prange step (dynamic chunks of one tile: tiles are uneven): Gaussian by
  Gaussian, only over the tile rows of its box. A row of 16 pixels is a branch-free loop that
  LLVM vectorises, each lane doing exactly the reference's per-pixel test (lanes outside the box
  masked off), so every pixel still composites front to back and the box only saves work.
  The loop covers the whole row although boxes are ~8 px wide: LLVM vectorises 16 lanes in one
  pass (AVX-512: one zmm; AVX2: two ymm), while 8-lane groups fell short of its vector body
  (16 wide on AVX-512, or 8 wide unrolled twice on AVX2) and ran in 4-wide remainder loops:
  whole rows made the forward ~15 % and the backward ~25 % faster (SUN3D map, 320 x 240; same
  results bit for bit). Making that loop vectorise needed: an exp LLVM can inline (`_exp`), flat
  per-tile state with compile-time field offsets, views so indices are provably >= 0,
  error_model="numpy" (no zero-division branch) and no "new if cond else old" stores (LLVM emits
  masked stores for those, which are very slow on AMD).
- The two compositing kernels let LLVM fuse a multiply and an add into one FMA (`fastmath`
  "contract" alone: no reassociation, no approximations, so each pixel's sums keep their order;
  FMAs round once where a multiply and an add rounded twice). The forward walks a Gaussian's
  rows as one loop over the tile's flat per-pixel state, not a loop per row. Together ~10 % off
  a mapping iteration (docs/benchmarks.md, "Renderer").
- The forward keeps the final transmittance and the last contributing list position per pixel;
  the backward walks each tile's list back to front, recovering T_i = T_{i+1} / (1 - a_i).
- Deterministic gradients without atomics: the backward writes one gradient row per
  (tile, Gaussian) intersection; a second kernel sums each Gaussian's rows in a fixed order.
- float32 inputs stay float32 inside the kernels (constants and pixel coordinates are passed in
  arrays of the input dtype, because Numba promotes float32 op float64-literal to float64).
  float64 inputs run the same kernels in float64 (with libm exp): that is what gradcheck uses.
- Features are composited 4 channels at a time (RGB + depth in practice); other channel counts
  are zero-padded and split into blocks of 4.

Numba's "workqueue" threading layer must not be entered from two threads at once, so every
kernel call runs inside `splat_core.parallel.numba_lock()` (a lock unless the layer in use is
thread-safe; the tracker, the mapper, the SLAM worker and the viewer all render).
"""

from __future__ import annotations

import math
import time

import numba
import numpy as np
import torch
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic, overload

from ..parallel import numba_lock
from ._constants import ALPHA_MAX, ALPHA_MIN, T_MIN, TILE

# The bounding boxes solve q(d) <= K * (1 + SPAN_SLACK) + SPAN_SLACK, a little more than the exact
# cutoff, so that rounding in the box arithmetic never drops a pixel the per-pixel test would keep.
# The per-pixel test alone decides what is composited (and lanes outside the box are masked off,
# identically in forward and backward).
SPAN_SLACK = 0.01


# Layout of the `consts` array handed to the kernels (in the working dtype).
(_C_ALPHA_MAX, _C_ALPHA_MIN, _C_T_MIN, _C_HALF, _C_ONE, _C_ZERO, _C_TWO, _C_255, _C_SLACK, _C_WIDTH,
 _C_HEIGHT) = range(11)

# Layout of the per-Gaussian parameter rows (depth-sorted, live Gaussians only).
_P_MX, _P_MY, _P_A, _P_B, _P_C, _P_O, _P_K, _P_DET = range(8)   # K, det: box inputs (kept for inspection)
_P_WIDTH = 8

# Layout of a per-intersection gradient row: means2d (2), conic (3), opacity (1), features (C).
_G_MX, _G_MY, _G_A, _G_B, _G_C, _G_O = range(6)
_G_FEAT = 6

last_stats: dict = {}   # what the most recent forward / backward measured (for benchmarks)


# ----------------------------------------------------------------------------- kernels

@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _prepare_gaussians(order, means2d, conics, opacities, width, height, consts, tile_table,
                       params, boxes, drawn):
    """Per live Gaussian (order[j]: its index): packed parameters and covered pixel box.

    boxes[j] = (x0, x1, y0, y1) inclusive pixel bounds; x0 > x1 when nothing can be covered.
    drawn[j]: the box reaches a chosen tile, counted in four reads of tile_table (`tile_table`:
    a summed-area table of the chosen tiles; a loop over the box's tiles took half the kernel's
    time, its trip counts of one or two being unpredictable).
    """
    one = consts[_C_ONE]
    zero = consts[_C_ZERO]
    two = consts[_C_TWO]
    c255 = consts[_C_255]
    slack = consts[_C_SLACK]
    amin = consts[_C_ALPHA_MIN]
    wf = consts[_C_WIDTH]
    hf = consts[_C_HEIGHT]
    for j in prange(order.shape[0]):
        g = order[j]
        mx = means2d[g, 0]
        my = means2d[g, 1]
        A = conics[g, 0]
        B = conics[g, 1]
        C = conics[g, 2]
        o = opacities[g]
        params[j, _P_MX] = mx
        params[j, _P_MY] = my
        params[j, _P_A] = A
        params[j, _P_B] = B
        params[j, _P_C] = C
        params[j, _P_O] = o
        boxes[j, 0] = 0
        boxes[j, 1] = -1
        boxes[j, 2] = 0
        boxes[j, 3] = -1
        drawn[j] = False
        params[j, _P_K] = zero
        params[j, _P_DET] = zero
        # alpha <= o everywhere (exp(power) <= 1 where power <= 0): below 1/255 it never counts.
        if not (o >= amin):
            continue
        det = A * C - B * B
        K = two * math.log(c255 * o)
        K = K + K * slack + slack
        if not (det > zero and A > zero and C > zero and K > zero):
            continue
        ex = math.sqrt(K * C / det)   # half-widths of the ellipse's bounding box
        ey = math.sqrt(K * A / det)
        xlo = mx - ex
        xhi = mx + ex
        ylo = my - ey
        yhi = my + ey
        # Clamp in floating point before converting (extents may be huge or infinite; NaN fails).
        if not (xhi >= zero and xlo <= wf - one and yhi >= zero and ylo <= hf - one):
            continue
        if xlo < -one:
            xlo = -one
        if ylo < -one:
            ylo = -one
        if xhi > wf:
            xhi = wf
        if yhi > hf:
            yhi = hf
        x0 = max(int(math.ceil(xlo)), 0)
        x1 = min(int(math.floor(xhi)), width - 1)
        y0 = max(int(math.ceil(ylo)), 0)
        y1 = min(int(math.floor(yhi)), height - 1)
        if x0 > x1 or y0 > y1:
            continue
        params[j, _P_K] = K
        params[j, _P_DET] = det
        boxes[j, 0] = x0
        boxes[j, 1] = x1
        boxes[j, 2] = y0
        boxes[j, 3] = y1
        tx0, tx1, ty0, ty1 = x0 // TILE, x1 // TILE + 1, y0 // TILE, y1 // TILE + 1
        drawn[j] = tile_table[ty1, tx1] - tile_table[ty0, tx1] - tile_table[ty1, tx0] + tile_table[ty0, tx0] > 0


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _bin_to_tiles(boxes, ntx, nty, tile_mask, threads):
    """Counting sort of (tile, Gaussian) intersections, Gaussians in depth order within a tile.

    Only tiles with tile_mask[t] != 0 get lists (the others render empty). Returns gauss_offsets
    (L + 1: each Gaussian's intersections), tile_offsets (ntiles + 1), isect_gauss (sorted
    Gaussian index per intersection) and gauss_slots (for each Gaussian, in its own order, the
    intersections that belong to it).

    In parallel over contiguous chunks of Gaussians, one per thread (`threads`): each chunk counts
    its intersections per tile, its place in a tile's list follows the chunks before it, and it
    fills its places in Gaussian order, so the lists are those of a serial pass.

    The tile size is the compile-time TILE: a division by it compiles to a shift, where a
    run-time divisor cost a 64-bit division per box edge (the rasterizer's forward, binning
    included, was 3-6 % slower with it: docs/history/2026-12-06-mapper-cost.md, h13-itercost).
    """
    tile = TILE
    L = boxes.shape[0]
    ntiles = ntx * nty
    chunks = max(1, min(threads, L // 1024))
    counts = np.zeros((chunks, ntiles), dtype=np.int64)
    gauss_offsets = np.zeros(L + 1, dtype=np.int64)
    for c in prange(chunks):
        for j in range(c * L // chunks, (c + 1) * L // chunks):
            x0, x1, y0, y1 = boxes[j, 0], boxes[j, 1], boxes[j, 2], boxes[j, 3]
            count = 0
            if x0 <= x1:
                for ty in range(y0 // tile, y1 // tile + 1):
                    for tx in range(x0 // tile, x1 // tile + 1):
                        if tile_mask[ty * ntx + tx]:
                            counts[c, ty * ntx + tx] += 1
                            count += 1
            gauss_offsets[j + 1] = count
    for j in range(L):
        gauss_offsets[j + 1] += gauss_offsets[j]
    tile_offsets = np.zeros(ntiles + 1, dtype=np.int64)
    starts = np.empty((chunks, ntiles), dtype=np.int64)
    for t in range(ntiles):
        pos = tile_offsets[t]
        for c in range(chunks):
            starts[c, t] = pos
            pos += counts[c, t]
        tile_offsets[t + 1] = pos
    n = gauss_offsets[L]
    isect_gauss = np.empty(n, dtype=np.int32)
    gauss_slots = np.empty(n, dtype=np.int64)
    for c in prange(chunks):
        cursor = starts[c]
        for j in range(c * L // chunks, (c + 1) * L // chunks):
            x0, x1, y0, y1 = boxes[j, 0], boxes[j, 1], boxes[j, 2], boxes[j, 3]
            if x0 > x1:
                continue
            m = gauss_offsets[j]
            for ty in range(y0 // tile, y1 // tile + 1):
                for tx in range(x0 // tile, x1 // tile + 1):
                    t = ty * ntx + tx
                    if not tile_mask[t]:
                        continue
                    pos = cursor[t]
                    cursor[t] = pos + 1
                    isect_gauss[pos] = j
                    gauss_slots[m] = pos
                    m += 1
    return gauss_offsets, tile_offsets, isect_gauss, gauss_slots


@intrinsic
def _pow2_float32(typingctx, n):
    """2**n for an integral-valued float32 n in [-126, 127], from the exponent bits.

    Written as LLVM IR on 32-bit integers: Numba's own int() goes through int64, which AVX2
    cannot convert in vectors, and that would keep the loop scalar.
    """
    if n != types.float32:
        return None

    def codegen(context, builder, sig, args):
        i32 = ir.IntType(32)
        k = builder.fptosi(args[0], i32)
        bits = builder.shl(builder.add(k, ir.Constant(i32, 127)), ir.Constant(i32, 23))
        return builder.bitcast(bits, ir.FloatType())

    return types.float32(types.float32), codegen


def _exp(x):
    return math.exp(x)


@overload(_exp, inline="always")
def _exp_overload(x):
    """exp that LLVM can vectorise for float32 (libm's expf is a call, which blocks it).

    Range reduction x = n ln2 + r with ln2 split in two parts, a degree-6 polynomial for e^r
    (the classic Cephes expf coefficients) and 2^n from the exponent bits: about 1 ulp (measured
    max relative error 8e-8 on [-30, 0]). float64 keeps math.exp (exactness over speed).
    """
    if x == types.float32:
        def impl(x):
            x = min(max(x, np.float32(-87.0)), np.float32(88.0))
            n = np.floor(x * np.float32(1.4426950408889634) + np.float32(0.5))
            r = x - n * np.float32(0.693359375) - n * np.float32(-2.12194440e-4)
            p = np.float32(1.9875691500e-4)
            p = p * r + np.float32(1.3981999507e-3)
            p = p * r + np.float32(8.3334519073e-3)
            p = p * r + np.float32(4.1665795894e-2)
            p = p * r + np.float32(1.6666665459e-1)
            p = p * r + np.float32(5.0000001201e-1)
            e = p * r * r + r + np.float32(1.0)
            return e * _pow2_float32(n)
        return impl
    return lambda x: math.exp(x)


# Per-tile pixel state of the forward: st[field * TILE * TILE + row * TILE + lane] (one array with
# fields at compile-time offsets, so LLVM sees no aliasing), the pixels' coordinates among them.
_F_T, _F_ACC, _F_ALPHA, _F_LAST, _F_DONE, _F_X, _F_Y = 0, 1, 5, 6, 7, 8, 9
_F_N = 10
_NP = TILE * TILE   # pixels in a tile: the stride between the forward state's fields
# Per-tile pixel state of the backward.
_B_T, _B_S, _B_GAT, _B_LAST, _B_GI = 0, 1, 5, 6, 7
_B_N = 11


@njit(parallel=True, cache=True, nogil=True, error_model="numpy", fastmath={"contract"})
def _forward_kernel(params, features, boxes, tile_offsets, isect_gauss, xs, ys, consts,
                    width, height, lanes, ntx, image, alpha_out, t_final, last, tile_last):
    """Front-to-back compositing of one 4-channel feature block, one tile per prange step.

    Within a tile, Gaussian by Gaussian (depth order), over the tile rows its box covers: those
    rows' pixels are one branch-free loop (rows of `lanes` == TILE pixels one after another in the
    tile's flat state, `lanes` passed at run time so LLVM vectorises instead of unrolling), each
    pixel doing exactly the reference's per-pixel test (and pixels outside the Gaussian's box in x
    masked off).
    Outputs per pixel: image (4 channels), alpha, t_final (transmittance after the last kept
    Gaussian), last (1 + tile-list position of the last kept Gaussian, 0 if none); per tile:
    tile_last = max of `last`.
    """
    amax = consts[_C_ALPHA_MAX]
    amin = consts[_C_ALPHA_MIN]
    tmin = consts[_C_T_MIN]
    half = consts[_C_HALF]
    one = consts[_C_ONE]
    zero = consts[_C_ZERO]
    nty = (height + TILE - 1) // TILE
    dt = params.dtype
    for t in prange(ntx * nty):
        ty = t // ntx
        tx = t - ty * ntx
        px0 = tx * TILE
        py0 = ty * TILE
        ncols = min(px0 + TILE, width) - px0
        nrows = min(py0 + TILE, height) - py0
        st = np.zeros(_F_N * _NP, dtype=dt)     # [field * TILE * TILE + row * TILE + lane]
        for r in range(TILE):
            for i in range(TILE):
                e = r * TILE + i
                st[_F_X * _NP + e] = xs[px0 + i]
                st[_F_Y * _NP + e] = ys[py0 + r]
                st[_F_T * _NP + e] = one
                if i >= ncols:
                    st[_F_DONE * _NP + e] = one    # lanes past the image edge never count
        rlo = 0                                 # the rows that still have live pixels
        rhi = nrows - 1
        start = tile_offsets[t]
        end = tile_offsets[t + 1]
        kk = zero                               # 1 + position in the tile list
        for k in range(start, end):
            kk += one
            j = isect_gauss[k]
            mx = params[j, _P_MX]
            my = params[j, _P_MY]
            A = params[j, _P_A]
            B = params[j, _P_B]
            C = params[j, _P_C]
            o = params[j, _P_O]
            f0 = features[j, 0]
            f1 = features[j, 1]
            f2 = features[j, 2]
            f3 = features[j, 3]
            xlo = xs[boxes[j, 0]]
            xhi = xs[boxes[j, 1]]
            ra = max(boxes[j, 2] - py0, rlo)
            rb = min(boxes[j, 3] - py0, rhi)
            if ra <= rb:
                s = st[ra * TILE:]
                for i in range((rb - ra + 1) * lanes):
                    xv = s[_F_X * _NP + i]
                    dx = mx - xv
                    dy = my - s[_F_Y * _NP + i]
                    power = -half * (A * dx * dx + C * dy * dy) - B * dx * dy
                    a = o * _exp(power)
                    a = a if a < amax else amax
                    T = s[_F_T * _NP + i]
                    lastv = s[_F_LAST * _NP + i]
                    donev = s[_F_DONE * _NP + i]
                    tn = T * (one - a)
                    ok = ((power <= zero) & (a >= amin) & (donev == zero)
                          & (xv >= xlo) & (xv <= xhi))
                    keep = ok & (tn >= tmin)
                    # Updates are written as arithmetic on selected factors, not as "new if
                    # keep else old": LLVM turns the latter into masked stores, which are very
                    # slow on AMD cores. T * 1 == T and last + 0 == last exactly.
                    w = a * T if keep else zero
                    s[_F_ACC * _NP + i] += f0 * w
                    s[(_F_ACC + 1) * _NP + i] += f1 * w
                    s[(_F_ACC + 2) * _NP + i] += f2 * w
                    s[(_F_ACC + 3) * _NP + i] += f3 * w
                    s[_F_ALPHA * _NP + i] += w
                    s[_F_T * _NP + i] = T * ((one - a) if keep else one)
                    s[_F_LAST * _NP + i] = lastv + ((kk - lastv) if keep else zero)
                    s[_F_DONE * _NP + i] = donev + (one if (ok & (tn < tmin)) else zero)
            if (k - start) % 16 == 15:
                # Every 16 Gaussians: narrow the band of rows with live pixels; stop the tile
                # when none is left. (Counting stops inside the pixel loop would block
                # vectorisation.)
                while rlo <= rhi and _row_done(st, rlo, ncols, zero):
                    rlo += 1
                while rhi >= rlo and _row_done(st, rhi, ncols, zero):
                    rhi -= 1
                if rlo > rhi:
                    break
        tl = 0
        for r in range(nrows):
            for i in range(ncols):
                y = py0 + r
                x = px0 + i
                e = r * TILE + i
                t_final[y, x] = st[_F_T * _NP + e]
                alpha_out[y, x] = st[_F_ALPHA * _NP + e]
                lk = int(st[_F_LAST * _NP + e])
                last[y, x] = lk
                tl = max(tl, lk)
                for c in range(4):
                    image[y, x, c] = st[(_F_ACC + c) * _NP + e]
        tile_last[t] = tl


@njit(cache=True, nogil=True, inline="always")
def _row_done(st, r, ncols, zero):
    """Whether every pixel of row r of a tile's forward state has stopped compositing."""
    for i in range(ncols):
        if st[_F_DONE * _NP + r * TILE + i] == zero:
            return False
    return True


@njit(parallel=True, cache=True, nogil=True, error_model="numpy", fastmath={"contract"})
def _backward_kernel(params, features, boxes, tile_offsets, isect_gauss, xs, ys, consts,
                     width, height, lanes, ntx, t_final, last, tile_last, grad_image, grad_alpha,
                     isect_grads):
    """Back-to-front recursion per tile for one 4-channel block; one gradient row per intersection.

    For a pixel with kept Gaussians i (front to back), T_i = prod_{j<i} (1 - a_j):
      dOut_c/da_i = T_i f_ic - S_ic / (1 - a_i),  S_ic = sum_{j>i} f_jc a_j T_j
      dAlpha/da_i = T_final / (1 - a_i)
      dOut_c/df_ic = a_i T_i
    and a_i = o G (G = exp(power)) unless clamped at 0.99 (then no gradient to o, power).
    T_i is recovered from T_{i+1} by division, starting from the stored T_final.
    Lane-wise sums per Gaussian (gl) are reduced over lanes in a fixed order: deterministic.
    """
    amax = consts[_C_ALPHA_MAX]
    amin = consts[_C_ALPHA_MIN]
    half = consts[_C_HALF]
    one = consts[_C_ONE]
    zero = consts[_C_ZERO]
    nty = (height + TILE - 1) // TILE
    ng = isect_grads.shape[1]
    dt = params.dtype
    for t in prange(ntx * nty):
        ty = t // ntx
        tx = t - ty * ntx
        px0 = tx * TILE
        py0 = ty * TILE
        ncols = min(px0 + TILE, width) - px0
        nrows = min(py0 + TILE, height) - py0
        start = tile_offsets[t]
        end = tile_offsets[t + 1]
        nk = tile_last[t]
        for k in range(start + nk, end):
            for q in range(ng):
                isect_grads[k, q] = zero
        if nk == 0:
            continue
        # Flat arrays with field offsets that are compile-time multiples of TILE: LLVM then
        # proves the fields disjoint and vectorises the lane loop (2-D views defeat it).
        st = np.zeros((TILE, _B_N * TILE), dtype=dt)   # [row][field * TILE + lane]
        gl = np.zeros((_G_FEAT + 4) * TILE, dtype=dt)   # [field][lane], per Gaussian
        rowlast = np.zeros(TILE, dtype=dt)                   # max `last` per row
        lx = xs[px0:px0 + TILE]
        for r in range(nrows):
            s = st[r]
            for i in range(ncols):
                y = py0 + r
                x = px0 + i
                s[_B_T * TILE + i] = t_final[y, x]
                s[_B_GAT * TILE + i] = grad_alpha[y, x] * t_final[y, x]   # dL/dAlpha T_final
                s[_B_LAST * TILE + i] = last[y, x]     # stored as the working dtype
                lf = s[_B_LAST * TILE + i]
                if lf > rowlast[r]:
                    rowlast[r] = lf
                for c in range(4):
                    s[(_B_GI + c) * TILE + i] = grad_image[y, x, c]
        kk = zero
        for r in range(nrows):
            kk = max(kk, rowlast[r])   # == tile_last[t] in the working dtype
        for k in range(start + nk - 1, start - 1, -1):
            j = isect_gauss[k]
            mx = params[j, _P_MX]
            my = params[j, _P_MY]
            A = params[j, _P_A]
            B = params[j, _P_B]
            C = params[j, _P_C]
            o = params[j, _P_O]
            f0 = features[j, 0]
            f1 = features[j, 1]
            f2 = features[j, 2]
            f3 = features[j, 3]
            xlo = xs[boxes[j, 0]]
            xhi = xs[boxes[j, 1]]
            ia = max(boxes[j, 0] - px0, 0)
            ib = min(boxes[j, 1] - px0, ncols - 1)
            for q in range(gl.shape[0]):   # all of it: a range from ia would compile to scatters
                gl[q] = zero
            for y in range(max(boxes[j, 2], py0), min(boxes[j, 3], py0 + nrows - 1) + 1):
                r = y - py0
                if kk > rowlast[r]:
                    continue
                dy = my - ys[y]
                s = st[r]
                for i in range(lanes):
                    xv = lx[i]
                    dx = mx - xv
                    power = -half * (A * dx * dx + C * dy * dy) - B * dx * dy
                    G = _exp(power)
                    a0 = o * G
                    clamped = a0 > amax
                    a = amax if clamped else a0
                    ok = ((power <= zero) & (a >= amin) & (kk <= s[_B_LAST * TILE + i])
                          & (xv >= xlo) & (xv <= xhi))
                    inv = one / (one - a)
                    Tn = s[_B_T * TILE + i]
                    T = Tn * inv
                    w = a * T
                    g0 = s[_B_GI * TILE + i]
                    g1 = s[(_B_GI + 1) * TILE + i]
                    g2 = s[(_B_GI + 2) * TILE + i]
                    g3 = s[(_B_GI + 3) * TILE + i]
                    S0 = s[_B_S * TILE + i]
                    S1 = s[(_B_S + 1) * TILE + i]
                    S2 = s[(_B_S + 2) * TILE + i]
                    S3 = s[(_B_S + 3) * TILE + i]
                    g_a = (s[_B_GAT * TILE + i] * inv
                           + g0 * (T * f0 - S0 * inv) + g1 * (T * f1 - S1 * inv)
                           + g2 * (T * f2 - S2 * inv) + g3 * (T * f3 - S3 * inv))
                    # No "new if ok else old" (masked stores, slow on AMD): add zero / scale by one.
                    wk = w if ok else zero
                    s[_B_S * TILE + i] = S0 + f0 * wk
                    s[(_B_S + 1) * TILE + i] = S1 + f1 * wk
                    s[(_B_S + 2) * TILE + i] = S2 + f2 * wk
                    s[(_B_S + 3) * TILE + i] = S3 + f3 * wk
                    s[_B_T * TILE + i] = Tn * (inv if ok else one)
                    gl[_G_FEAT * TILE + i] += wk * g0
                    gl[(_G_FEAT + 1) * TILE + i] += wk * g1
                    gl[(_G_FEAT + 2) * TILE + i] += wk * g2
                    gl[(_G_FEAT + 3) * TILE + i] += wk * g3
                    live = ok & (not clamped)
                    g_pow = g_a * a if live else zero
                    gl[_G_O * TILE + i] += g_a * G if live else zero
                    gl[_G_MX * TILE + i] -= g_pow * (A * dx + B * dy)
                    gl[_G_MY * TILE + i] -= g_pow * (C * dy + B * dx)
                    gl[_G_A * TILE + i] -= g_pow * half * dx * dx
                    gl[_G_B * TILE + i] -= g_pow * dx * dy
                    gl[_G_C * TILE + i] -= g_pow * half * dy * dy
            # Each field's lanes summed in lane order (ia..ib), the ten fields side by side: ten
            # independent add chains instead of one field's chain after another (same sums).
            a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = a8 = a9 = zero
            for i in range(ia, ib + 1):
                a0 += gl[_G_MX * TILE + i]
                a1 += gl[_G_MY * TILE + i]
                a2 += gl[_G_A * TILE + i]
                a3 += gl[_G_B * TILE + i]
                a4 += gl[_G_C * TILE + i]
                a5 += gl[_G_O * TILE + i]
                a6 += gl[_G_FEAT * TILE + i]
                a7 += gl[(_G_FEAT + 1) * TILE + i]
                a8 += gl[(_G_FEAT + 2) * TILE + i]
                a9 += gl[(_G_FEAT + 3) * TILE + i]
            row = isect_grads[k]
            row[_G_MX] = a0
            row[_G_MY] = a1
            row[_G_A] = a2
            row[_G_B] = a3
            row[_G_C] = a4
            row[_G_O] = a5
            row[_G_FEAT] = a6
            row[_G_FEAT + 1] = a7
            row[_G_FEAT + 2] = a8
            row[_G_FEAT + 3] = a9
            kk -= one


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _reduce_grads(order, gauss_offsets, gauss_slots, isect_grads, zero, grad_means2d, grad_conics,
                  grad_opacities, grad_features):
    """Sum each Gaussian's intersection rows in a fixed order (deterministic, no atomics)."""
    for j in prange(order.shape[0]):
        a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = a8 = a9 = zero
        for m in range(gauss_offsets[j], gauss_offsets[j + 1]):
            row = isect_grads[gauss_slots[m]]
            a0 += row[_G_MX]
            a1 += row[_G_MY]
            a2 += row[_G_A]
            a3 += row[_G_B]
            a4 += row[_G_C]
            a5 += row[_G_O]
            a6 += row[_G_FEAT]
            a7 += row[_G_FEAT + 1]
            a8 += row[_G_FEAT + 2]
            a9 += row[_G_FEAT + 3]
        g = order[j]
        grad_means2d[g, 0] = a0
        grad_means2d[g, 1] = a1
        grad_conics[g, 0] = a2
        grad_conics[g, 1] = a3
        grad_conics[g, 2] = a4
        grad_opacities[g] = a5
        grad_features[g, 0] = a6
        grad_features[g, 1] = a7
        grad_features[g, 2] = a8
        grad_features[g, 3] = a9


# ----------------------------------------------------------------------------- driver

class _Binned:
    """Everything the backward needs from the forward (numpy arrays)."""

    __slots__ = ("order", "params", "blocks", "nch", "boxes", "gauss_offsets", "tile_offsets",
                 "isect_gauss", "gauss_slots", "xs", "ys", "consts", "width", "height", "ntx",
                 "t_final", "last", "tile_last", "n")


def tile_table(mask: np.ndarray, ntx: int, nty: int) -> np.ndarray:
    """Summed-area table of a tile mask: table[ty, tx] = chosen tiles in rows < ty, columns < tx."""
    table = np.zeros((nty + 1, ntx + 1), dtype=np.int64)
    table[1:, 1:] = (np.asarray(mask).reshape(nty, ntx) != 0).cumsum(0).cumsum(1)
    return table


def _consts(dtype, width, height) -> np.ndarray:
    c = np.zeros(11, dtype=dtype)
    c[_C_ALPHA_MAX] = ALPHA_MAX
    c[_C_ALPHA_MIN] = ALPHA_MIN
    c[_C_T_MIN] = T_MIN
    c[_C_HALF] = 0.5
    c[_C_ONE] = 1.0
    c[_C_ZERO] = 0.0
    c[_C_TWO] = 2.0
    c[_C_255] = 255.0
    c[_C_SLACK] = SPAN_SLACK
    c[_C_WIDTH] = width
    c[_C_HEIGHT] = height
    return c


def _np(t: torch.Tensor, dtype) -> np.ndarray:
    tdt = torch.float64 if dtype == np.float64 else torch.float32
    return np.ascontiguousarray(t.detach().to(device="cpu", dtype=tdt).numpy())


@njit(cache=True, nogil=True)
def _radix_argsort(keys):
    """Stable argsort of non-negative int32 keys: LSD radix sort on 11-bit digits (a digit
    that all keys share is skipped)."""
    n = keys.shape[0]
    idx = np.arange(n)
    tmp = np.empty(n, np.int64)
    k = keys.copy()
    kt = np.empty_like(k)
    for shift in (0, 11, 22):
        counts = np.zeros(2049, np.int64)
        for i in range(n):
            counts[((k[i] >> shift) & 2047) + 1] += 1
        if counts.max() == n:
            continue
        for d in range(2048):
            counts[d + 1] += counts[d]
        for i in range(n):
            d = (k[i] >> shift) & 2047
            p = counts[d]
            counts[d] = p + 1
            tmp[p] = idx[i]
            kt[p] = k[i]
        idx, tmp = tmp, idx
        k, kt = kt, k
    return idx


def depth_order(depth_np: np.ndarray) -> np.ndarray:
    """Stable argsort of depths (ties by index). Positive IEEE floats sort like their bit patterns
    read as integers: float32 depths by a radix sort of those bits (4-5x numpy's stable argsort),
    float64 (gradcheck) and anything else by numpy."""
    if depth_np.dtype == np.float32 and bool((depth_np > 0).all()):
        return _radix_argsort(depth_np.view(np.int32))
    return np.argsort(depth_np, kind="stable")


@njit(parallel=True, cache=True, nogil=True)
def _gather_sorted(pick, live, params, boxes, features, order, params_out, boxes_out, blocks_out):
    """Rows `pick` of (live, params, boxes), in that order (numpy's fancy indexing is serial),
    and the features of those Gaussians as blocks of 4 channels (zero-padded; the kernels
    composite 4 channels at a time): blocks_out[b, j, c] = features[order[j], 4 b + c]."""
    nch = features.shape[1]
    for j in prange(pick.shape[0]):
        i = pick[j]
        g = live[i]
        order[j] = g
        for q in range(params.shape[1]):
            params_out[j, q] = params[i, q]
        for q in range(4):
            boxes_out[j, q] = boxes[i, q]
        for q in range(blocks_out.shape[0] * 4):
            blocks_out[q // 4, j, q % 4] = features[g, q] if q < nch else 0


def _bin(means2d, conics, opacities, features, depths, radii, width, height, dtype, stats, tiles=None):
    """Per-Gaussian boxes, depth sort and tile lists (torch in, _Binned out); `tiles`: see rasterize_cpu.

    Only Gaussians whose box reaches a chosen tile (every tile without `tiles`) are sorted and binned."""
    t0 = time.perf_counter()
    b = _Binned()
    b.n = means2d.shape[0]
    b.consts = _consts(dtype, width, height)
    b.width, b.height = int(width), int(height)
    b.ntx = (b.width + TILE - 1) // TILE
    nty = (b.height + TILE - 1) // TILE
    if tiles is None:
        mask = np.ones(b.ntx * nty, dtype=np.uint8)
    else:
        mask = np.ascontiguousarray(np.asarray(tiles, dtype=np.uint8).reshape(-1))
        if mask.shape[0] != b.ntx * nty:
            raise ValueError(f"tiles: expected {nty} x {b.ntx} tiles of {TILE} px, got {np.shape(tiles)}")
    live = np.flatnonzero(radii.detach().cpu().numpy() > 0)
    params = np.empty((live.shape[0], _P_WIDTH), dtype=dtype)
    boxes = np.empty((live.shape[0], 4), dtype=np.int64)
    drawn = np.empty(live.shape[0], dtype=np.bool_)
    _prepare_gaussians(live, _np(means2d, dtype), _np(conics, dtype), _np(opacities, dtype),
                       b.width, b.height, b.consts, tile_table(mask, b.ntx, nty), params, boxes, drawn)
    drawn = np.flatnonzero(drawn)
    pick = drawn[depth_order(depths.detach().cpu().numpy()[live[drawn]])]   # positions in `live`, front to back
    L = pick.shape[0]
    b.order, b.params, b.boxes = np.empty(L, np.int64), np.empty((L, _P_WIDTH), dtype), np.empty((L, 4), np.int64)
    feats = np.zeros((b.n, 0), dtype) if features is None else _np(features, dtype)
    b.nch = feats.shape[1]
    blocks = np.empty((-(-b.nch // 4), L, 4), dtype)
    _gather_sorted(pick, live, params, boxes, feats, b.order, b.params, b.boxes, blocks)
    b.blocks = list(blocks)
    t1 = time.perf_counter()
    lists = _bin_to_tiles(b.boxes, b.ntx, nty, mask, numba.get_num_threads())
    b.gauss_offsets, b.tile_offsets, b.isect_gauss, b.gauss_slots = lists
    # Pixel coordinates in the working dtype, padded to whole tiles (lanes past the edge).
    b.xs = np.arange(b.ntx * TILE, dtype=dtype)
    b.ys = np.arange(nty * TILE, dtype=dtype)
    t2 = time.perf_counter()
    stats.update(sort_ms=1e3 * (t1 - t0), binning_ms=1e3 * (t2 - t1),
                 intersections=int(b.gauss_offsets[L]), live=int(L), tiles=b.ntx * nty)
    return b


class _TileChunks:
    """Dynamic scheduling for the tile kernels: chunks of one tile (tiles are very uneven).

    Set from Python (a `with numba.parallel_chunksize` block inside a cached kernel breaks
    Numba's cache); the setting is thread-local in Numba, so concurrent callers do not share it.
    """

    def __enter__(self):
        self.old = numba.get_parallel_chunksize()
        numba.set_parallel_chunksize(1)

    def __exit__(self, *exc):
        numba.set_parallel_chunksize(self.old)


def _working_dtype(t: torch.Tensor):
    return np.float64 if t.dtype == torch.float64 else np.float32


def count_intersections(means2d, conics, opacities, radii, width: int, height: int) -> int:
    """Number of (tile, Gaussian) pairs the CPU rasterizer processes for these inputs."""
    with numba_lock():
        b = _bin(means2d, conics, opacities, None, torch.zeros(means2d.shape[0]), radii,
                 width, height, _working_dtype(means2d), {})
    return int(b.gauss_offsets[-1])


def _forward(means2d, conics, opacities, features, depths, radii, width, height, tiles=None):
    dtype = _working_dtype(means2d)
    stats = {}
    with numba_lock():
        b = _bin(means2d, conics, opacities, features, depths, radii, width, height, dtype, stats, tiles)
        H, W = b.height, b.width
        t0 = time.perf_counter()
        images = []
        for i, block in enumerate(b.blocks):
            image = np.empty((H, W, 4), dtype=dtype)
            alpha = np.empty((H, W), dtype=dtype)
            t_final = np.empty((H, W), dtype=dtype)
            last = np.empty((H, W), dtype=np.int64)
            tile_last = np.empty(b.tile_offsets.shape[0] - 1, dtype=np.int64)
            with _TileChunks():
                _forward_kernel(b.params, block, b.boxes, b.tile_offsets, b.isect_gauss, b.xs,
                                b.ys, b.consts, W, H, TILE, b.ntx, image, alpha, t_final, last,
                                tile_last)
            images.append(image)
            if i == 0:   # every block composites the same alphas: keep the first block's state
                b.t_final, b.last, b.tile_last, alpha0 = t_final, last, tile_last, alpha
        image = images[0] if len(images) == 1 else np.concatenate(images, axis=2)
        stats["forward_kernel_ms"] = 1e3 * (time.perf_counter() - t0)
    last_stats.clear()
    last_stats.update(stats)
    return np.ascontiguousarray(image[..., :b.nch]), alpha0, b


def _backward(b: _Binned, grad_image: np.ndarray, grad_alpha: np.ndarray):
    dtype = b.params.dtype
    H, W, C = b.height, b.width, b.nch
    g_m = np.zeros((b.n, 2), dtype=dtype)
    g_q = np.zeros((b.n, 3), dtype=dtype)
    g_o = np.zeros(b.n, dtype=dtype)
    g_f = np.zeros((b.n, 4 * len(b.blocks)), dtype=dtype)
    t_kernel = t_reduce = 0.0
    with numba_lock():
        for i, block in enumerate(b.blocks):
            t0 = time.perf_counter()
            if C == 4 and grad_image.shape == (H, W, 4) and grad_image.dtype == dtype:
                gi = np.ascontiguousarray(grad_image)       # one whole block: no copy needed
            else:
                gi = np.zeros((H, W, 4), dtype=dtype)
                gi[..., :max(0, min(4, C - 4 * i))] = grad_image[..., 4 * i:4 * i + 4]
            # dAlpha/da enters once, with the first block; the other blocks add colour terms only.
            ga = grad_alpha if i == 0 else np.zeros_like(grad_alpha)
            isect_grads = np.empty((b.isect_gauss.shape[0], _G_FEAT + 4), dtype=dtype)
            with _TileChunks():
                _backward_kernel(b.params, block, b.boxes, b.tile_offsets, b.isect_gauss, b.xs,
                                 b.ys, b.consts, W, H, TILE, b.ntx, b.t_final, b.last,
                                 b.tile_last, gi, ga, isect_grads)
            t1 = time.perf_counter()
            if len(b.blocks) == 1:
                # One block: its sums are the gradients (a sum that starts at +0 is never -0, so
                # this equals adding them to zeros, bit for bit).
                _reduce_grads(b.order, b.gauss_offsets, b.gauss_slots, isect_grads, b.consts[_C_ZERO],
                              g_m, g_q, g_o, g_f)
            else:
                bm = np.zeros((b.n, 2), dtype=dtype)
                bq = np.zeros((b.n, 3), dtype=dtype)
                bo = np.zeros(b.n, dtype=dtype)
                bf = np.zeros((b.n, 4), dtype=dtype)
                _reduce_grads(b.order, b.gauss_offsets, b.gauss_slots, isect_grads, b.consts[_C_ZERO],
                              bm, bq, bo, bf)
                g_m += bm
                g_q += bq
                g_o += bo
                g_f[:, 4 * i:4 * i + 4] = bf
            t_kernel += t1 - t0
            t_reduce += time.perf_counter() - t1
    last_stats.update(backward_kernel_ms=1e3 * t_kernel, reduce_ms=1e3 * t_reduce)
    return g_m, g_q, g_o, np.ascontiguousarray(g_f[:, :C])


class _RasterizeCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, depths, radii, width, height, tiles):
        image, alpha, binned = _forward(means2d, conics, opacities, features, depths, radii,
                                        width, height, tiles)
        ctx.binned = binned
        ctx.like = (means2d.dtype, means2d.device)
        dtype, device = ctx.like
        return (torch.from_numpy(image).to(device, dtype), torch.from_numpy(alpha).to(device, dtype))

    @staticmethod
    def backward(ctx, grad_image, grad_alpha):
        b = ctx.binned
        dtype, device = ctx.like
        wd = b.params.dtype
        H, W, C = b.height, b.width, b.nch
        gi = np.zeros((H, W, C), dtype=wd) if grad_image is None else _np(grad_image, wd)
        ga = np.zeros((H, W), dtype=wd) if grad_alpha is None else _np(grad_alpha, wd)
        g = _backward(b, gi, ga)
        g_m, g_q, g_o, g_f = (torch.from_numpy(x).to(device, dtype) for x in g)
        return g_m, g_q, g_o, g_f, None, None, None, None, None


def rasterize_cpu(means2d, conics, opacities, features, depths, radii, width, height, tiles=None):
    """Composite screen-space Gaussians front to back (same contract as `rasterize_reference`).

    means2d N x 2, conics N x 3, opacities N, features N x C, depths N (sort key only), radii N
    (0 = culled). Returns (H x W x C feature image, H x W accumulated alpha). Differentiable
    w.r.t. means2d, conics, opacities and features.
    tiles: None, or a boolean grid (ceil(H / TILE) x ceil(W / TILE)) of the TILE x TILE pixel
    tiles to composite; the others come back empty (features 0, alpha 0) and cost nothing.
    """
    return _RasterizeCPU.apply(means2d, conics, opacities, features, depths, radii,
                               int(width), int(height), tiles)
