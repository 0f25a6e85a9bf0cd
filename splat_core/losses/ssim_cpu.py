"""Mean SSIM of a rendered image against a constant target on the CPU: Numba kernels with an
analytic backward (what `losses.ssim` runs for CPU tensors).

Same definition as `losses.ssim_map(...).mean()` (the torch reference): an 11-tap Gaussian window
(sigma 1.5) applied as a horizontal then a vertical 1D pass with zero padding, C1 = 0.01^2,
C2 = 0.03^2. With mu_x = blur(x), mu_y = blur(y), sigma_xy = blur(xy) - mu_x mu_y (likewise
sigma_x^2, sigma_y^2):

    S = A1 A2 / (B1 B2),  A1 = 2 mu_x mu_y + C1,  A2 = 2 sigma_xy + C2,
                          B1 = mu_x^2 + mu_y^2 + C1,  B2 = sigma_x^2 + sigma_y^2 + C2.

Gradient with respect to x (y is a constant target): per pixel, with D = B1 B2,

    dS/dmu_x     = 2 (mu_y (A2 - A1) - mu_x S (B2 - B1)) / D
    dS/dblur(xx) = -S / B2
    dS/dblur(xy) = 2 A1 / D

(the partials treat mu_x, blur(x^2), blur(xy) as independent). The blur is self-adjoint (symmetric
taps, zero padding), so

    d mean(S) / dx = (blur(dS/dmu_x) + 2 x blur(dS/dblur(xx)) + y blur(dS/dblur(xy))) / N.

Layout: an H x W x C image is read as H rows of L = W C values (channel-last). The horizontal
pass is then a 1D convolution of each flat row with taps C apart (a tap that leaves the row is a
pixel outside the image, so zero padding of the flat row is zero padding of every channel); the
vertical pass combines whole rows. Both run as prange over image rows, inner loops over contiguous
values with the 11 taps unrolled, which LLVM vectorises. Zero padding is done with zeroed margins
(5 C values each side of a row, 5 rows above and below the horizontally blurred images), so no
loop has edge branches. What vectorisation needed: a compile-time tap stride (C = 3 and C = 1 get
their own copy of the horizontal loop; other channel counts run it with a runtime stride, correct
but several times slower) and stores through one array (see `_hblur5`).

The forward, when x needs a gradient, keeps the three per-pixel partials (computed from the five
blurred images while they are at hand) instead of the blurred images themselves: the backward
then only blurs those three maps and combines them with x and y.

float32 stays float32 in the kernels (constants come in an array of the input dtype, because
Numba promotes float32 op float64-literal to float64); only each row's sum of the SSIM map is
accumulated in float64. float64 runs in float64 throughout (gradcheck). Every kernel call runs
inside `parallel.numba_lock()`.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange

from ..parallel import numba_lock
from ._torch_impl import gaussian_window_1d

WIN = 11            # taps (a compile-time constant in the kernels: the tap loops unroll)
HALF = WIN // 2     # zero padding on each side
C1 = 0.01 ** 2
C2 = 0.03 ** 2

# Layout of the `consts` array handed to the kernels (in the working dtype).
_K_ZERO, _K_ONE, _K_TWO, _K_C1, _K_C2, _K_SCALE = range(6)


# ----------------------------------------------------------------------------- kernels

@njit(inline="always")
def _hblur5(xr, yr, g, zero, C, L, hbuf, row):
    """Horizontal pass of one zero-padded row pair (taps C apart): x, y, xx, yy, xy into
    hbuf[0..4, row]. (Stores through one array: five separate row views need more runtime alias
    checks than LLVM allows, and the loop would not vectorise.)"""
    for m in range(L):
        sx = zero
        sy = zero
        sxx = zero
        syy = zero
        sxy = zero
        for k in range(WIN):
            w = g[k]
            a = xr[m + k * C]
            b = yr[m + k * C]
            sx += w * a
            sy += w * b
            sxx += w * (a * a)
            syy += w * (b * b)
            sxy += w * (a * b)
        hbuf[0, row, m] = sx
        hbuf[1, row, m] = sy
        hbuf[2, row, m] = sxx
        hbuf[3, row, m] = syy
        hbuf[4, row, m] = sxy


@njit(inline="always")
def _hblur3(ur, vr, wr, g, zero, C, L, hbuf, row):
    """Horizontal pass of three zero-padded rows (taps C apart) into hbuf[0..2, row]."""
    for m in range(L):
        su = zero
        sv = zero
        sw = zero
        for k in range(WIN):
            w = g[k]
            su += w * ur[m + k * C]
            sv += w * vr[m + k * C]
            sw += w * wr[m + k * C]
        hbuf[0, row, m] = su
        hbuf[1, row, m] = sv
        hbuf[2, row, m] = sw


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _forward_kernel(x, y, C, g, consts, want_grad, hbuf, rowsum, d_mu, d_xx, d_xy):
    """x, y: H x L (L = W C). g: the WIN taps. hbuf: 5 x (H + 2 HALF) x L scratch (horizontally
    blurred x, y, xx, yy, xy with HALF zero rows above and below; filled here). rowsum (float64,
    H): sum of each row of the SSIM map. With want_grad, d_mu, d_xx, d_xy (H x L) receive
    dS/dmu_x, 2 dS/dblur(xx) and dS/dblur(xy) per pixel (the 2 of 2 x blur(.) folded in)."""
    H, L = x.shape
    P = HALF * C
    zero = consts[_K_ZERO]
    one = consts[_K_ONE]
    two = consts[_K_TWO]
    c1 = consts[_K_C1]
    c2 = consts[_K_C2]
    for q in prange(5):                         # the zero rows of the vertical padding
        for t in range(HALF):
            for m in range(L):
                hbuf[q, t, m] = zero
                hbuf[q, H + HALF + t, m] = zero
    for i in prange(H):                         # horizontal pass
        xr = np.empty(L + 2 * P, x.dtype)
        yr = np.empty(L + 2 * P, x.dtype)
        for m in range(P):
            xr[m] = zero
            yr[m] = zero
            xr[P + L + m] = zero
            yr[P + L + m] = zero
        for m in range(L):
            xr[P + m] = x[i, m]
            yr[P + m] = y[i, m]
        row = i + HALF
        # A compile-time tap stride for the usual channel counts (with a runtime stride LLVM's
        # vectorised loop was several times slower).
        if C == 3:
            _hblur5(xr, yr, g, zero, 3, L, hbuf, row)
        elif C == 1:
            _hblur5(xr, yr, g, zero, 1, L, hbuf, row)
        else:
            _hblur5(xr, yr, g, zero, C, L, hbuf, row)
    for i in prange(H):                         # vertical pass, SSIM map and partials
        srow = np.empty(L, x.dtype)
        for m in range(L):
            mx = zero
            my = zero
            exx = zero
            eyy = zero
            exy = zero
            for k in range(WIN):
                w = g[k]
                mx += w * hbuf[0, i + k, m]
                my += w * hbuf[1, i + k, m]
                exx += w * hbuf[2, i + k, m]
                eyy += w * hbuf[3, i + k, m]
                exy += w * hbuf[4, i + k, m]
            mxx = mx * mx
            myy = my * my
            mxy = mx * my
            a1 = two * mxy + c1
            a2 = two * (exy - mxy) + c2
            b1 = mxx + myy + c1
            b2 = (exx - mxx) + (eyy - myy) + c2
            d = b1 * b2
            s = (a1 * a2) / d
            srow[m] = s
            if want_grad:
                inv = one / d
                d_mu[i, m] = two * (my * (a2 - a1) - mx * s * (b2 - b1)) * inv
                d_xx[i, m] = -two * s * b1 * inv            # 2 dS/dblur(xx) = -2 S / B2
                d_xy[i, m] = two * a1 * inv
        acc = 0.0
        for m in range(L):
            acc += srow[m]
        rowsum[i] = acc


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _backward_kernel(x, y, d_mu, d_xx, d_xy, C, g, consts, hbuf, out):
    """out[i, m] = (blur(d_mu) + x blur(d_xx) + y blur(d_xy)) * scale (d_xx carries the 2).
    hbuf: 3 x (H + 2 HALF) x L scratch (filled here)."""
    H, L = x.shape
    P = HALF * C
    zero = consts[_K_ZERO]
    scale = consts[_K_SCALE]
    for q in prange(3):                         # the zero rows of the vertical padding
        for t in range(HALF):
            for m in range(L):
                hbuf[q, t, m] = zero
                hbuf[q, H + HALF + t, m] = zero
    for i in prange(H):                         # horizontal pass
        ur = np.empty(L + 2 * P, x.dtype)
        vr = np.empty(L + 2 * P, x.dtype)
        wr = np.empty(L + 2 * P, x.dtype)
        for m in range(P):
            ur[m] = zero
            vr[m] = zero
            wr[m] = zero
            ur[P + L + m] = zero
            vr[P + L + m] = zero
            wr[P + L + m] = zero
        for m in range(L):
            ur[P + m] = d_mu[i, m]
            vr[P + m] = d_xx[i, m]
            wr[P + m] = d_xy[i, m]
        row = i + HALF
        if C == 3:
            _hblur3(ur, vr, wr, g, zero, 3, L, hbuf, row)
        elif C == 1:
            _hblur3(ur, vr, wr, g, zero, 1, L, hbuf, row)
        else:
            _hblur3(ur, vr, wr, g, zero, C, L, hbuf, row)
    for i in prange(H):                         # vertical pass and the combination
        for m in range(L):
            su = zero
            sv = zero
            sw = zero
            for k in range(WIN):
                w = g[k]
                su += w * hbuf[0, i + k, m]
                sv += w * hbuf[1, i + k, m]
                sw += w * hbuf[2, i + k, m]
            out[i, m] = (su + x[i, m] * sv + y[i, m] * sw) * scale


# ----------------------------------------------------------------------------- driver

def _taps(dtype) -> np.ndarray:
    """The 1D window exactly as `losses._torch_impl.gaussian_window_1d` makes it, in the working dtype."""
    tdt = torch.float64 if dtype == np.float64 else torch.float32
    return np.ascontiguousarray(gaussian_window_1d(WIN, dtype=tdt).numpy())


_TAPS: dict = {}   # dtype -> taps


def _consts(dtype, scale: float = 0.0) -> np.ndarray:
    c = np.zeros(6, dtype=dtype)
    c[_K_ZERO] = 0.0
    c[_K_ONE] = 1.0
    c[_K_TWO] = 2.0
    c[_K_C1] = C1
    c[_K_C2] = C2
    c[_K_SCALE] = scale
    return c


def ssim_np(x: np.ndarray, y: np.ndarray, want_grad: bool):
    """Mean SSIM of x against the target y (numpy, H x W x C or H x W, one float dtype) and, when
    want_grad, the per-pixel partials that `ssim_grad_np` needs (else None)."""
    C = 1 if x.ndim == 2 else x.shape[2]
    x, y = _rows(x), _rows(y)
    dtype = x.dtype.type
    H, L = x.shape
    g = _TAPS.get(dtype)
    if g is None:
        g = _TAPS[dtype] = _taps(dtype)
    hbuf = np.empty((5, H + 2 * HALF, L), dtype=dtype)
    rowsum = np.empty(H, dtype=np.float64)
    if want_grad:
        d_mu, d_xx, d_xy = (np.empty((H, L), dtype=dtype) for _ in range(3))
    else:
        d_mu = d_xx = d_xy = np.empty((0, 0), dtype=dtype)
    with numba_lock():
        _forward_kernel(x, y, C, g, _consts(dtype), want_grad, hbuf, rowsum, d_mu, d_xx, d_xy)
    return float(rowsum.sum()) / x.size, ((d_mu, d_xx, d_xy) if want_grad else None)


def ssim_grad_np(x: np.ndarray, y: np.ndarray, partials, scale: float) -> np.ndarray:
    """scale * d mean SSIM / dx, shaped like x (partials from `ssim_np(x, y, True)`)."""
    shape, C = x.shape, 1 if x.ndim == 2 else x.shape[2]
    x, y = _rows(x), _rows(y)
    dtype = x.dtype.type
    H, L = x.shape
    out = np.empty((H, L), dtype=dtype)
    hbuf = np.empty((3, H + 2 * HALF, L), dtype=dtype)
    with numba_lock():
        _backward_kernel(x, y, *partials, C, _TAPS[dtype], _consts(dtype, scale / x.size), hbuf, out)
    return out.reshape(shape)


def _rows(a: np.ndarray) -> np.ndarray:
    """H x W x C (or H x W) array -> H x (W C) C-contiguous array (a view when possible)."""
    a = np.ascontiguousarray(a)
    return a.reshape(a.shape[0], -1)


class _SSIMCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, img1, img2, want_grad):
        x, y = img1.detach().numpy(), img2.detach().numpy()
        value, partials = ssim_np(x, y, want_grad)
        if want_grad:
            ctx.save_for_backward(img1, img2)
            ctx.partials = partials
        return torch.tensor(value, dtype=img1.dtype)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_out):
        if not ctx.needs_input_grad[0]:
            return None, None, None
        img1, img2 = ctx.saved_tensors
        grad = ssim_grad_np(img1.detach().numpy(), img2.detach().numpy(), ctx.partials, float(grad_out))
        return torch.from_numpy(grad), None, None


def ssim_cpu(img1: torch.Tensor, img2: torch.Tensor) -> torch.Tensor:
    """Mean SSIM (0-dim tensor) of two CPU images of the same shape (H x W x C or H x W) and float
    dtype (float32 or float64); differentiable with respect to img1 only (img2 is the target)."""
    if img1.shape != img2.shape:
        raise ValueError(f"ssim: shapes differ {tuple(img1.shape)} vs {tuple(img2.shape)}")
    if img1.dim() not in (2, 3):
        raise ValueError(f"expected an H x W or H x W x C image, got shape {tuple(img1.shape)}")
    if img1.dtype not in (torch.float32, torch.float64) or img2.dtype != img1.dtype:
        raise ValueError(f"ssim_cpu: float32 or float64 images of one dtype, got {img1.dtype}, "
                         f"{img2.dtype}")
    if img1.device.type != "cpu" or img2.device.type != "cpu":
        raise ValueError("ssim_cpu: CPU tensors only")
    if img2.requires_grad:
        raise ValueError("ssim_cpu: img2 is a constant target (losses.ssim_map gives its gradient)")
    if img1.numel() == 0:
        raise ValueError("ssim_cpu: empty image")
    # Function.forward sees needs_input_grad True even under torch.no_grad: decide here whether
    # the forward keeps the partials for a backward.
    want_grad = bool(img1.requires_grad and torch.is_grad_enabled())
    return _SSIMCPU.apply(img1, img2, want_grad)
