"""The losses' definitions in torch autograd: masked L1 and SSIM (the 3DGS definition; see
losses/__init__.py). A leaf: the dispatcher and the Numba kernels (ssim_cpu.py) import from here.
"""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2


def l1(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None,
       reduction: str = "sum") -> torch.Tensor:
    """L1 between `pred` and `target` (same shape, H x W or H x W x C).

    mask: optional H x W (or same shape as pred) selection; a bool mask selects pixels (NaN in
    unselected pixels does no harm), a float mask weights them. A H x W mask applies to every
    channel.
    reduction: "sum" (tracking: sum over selected pixels and channels), "mean" (mean over the
    selected pixel-channel values, weighted for a float mask; 0 when nothing is selected), or "none" (per-element, masked
    values 0).
    """
    if pred.shape != target.shape:
        raise ValueError(f"l1: shapes differ {tuple(pred.shape)} vs {tuple(target.shape)}")
    count = None
    if mask is None:
        diff = (pred - target).abs()
    else:
        if mask.dim() == pred.dim() - 1:
            mask = mask.unsqueeze(-1)
        mask = mask.expand_as(pred)
        if mask.dtype == torch.bool:
            # Select before subtracting: NaN/inf outside the mask then reach neither the value
            # nor the gradient (0 * NaN would poison both).
            zero = torch.zeros((), dtype=pred.dtype, device=pred.device)
            diff = (torch.where(mask, pred, zero) - torch.where(mask, target, zero)).abs()
            count = mask.sum().to(pred.dtype)
        else:
            mask = mask.to(pred.dtype)
            diff = (pred - target).abs() * mask
            count = mask.sum()
    if reduction == "sum":
        return diff.sum()
    if reduction == "mean":
        if count is None:
            return diff.mean()
        return diff.sum() / count.clamp_min(1e-12)   # nothing selected -> 0, not NaN
    if reduction == "none":
        return diff
    raise ValueError(f"reduction must be 'sum', 'mean' or 'none', got {reduction!r}")


def gaussian_window_1d(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA, *,
                       dtype=torch.float32, device=None) -> torch.Tensor:
    """Normalised 1D Gaussian window of `size` taps."""
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2.0
    g = torch.exp(-(x ** 2) / (2.0 * sigma ** 2))
    return (g / g.sum()).to(dtype=dtype, device=device)


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA, *,
                    dtype=torch.float32, device=None) -> torch.Tensor:
    """Normalised 2D Gaussian window (size x size), the outer product of the 1D window."""
    g = gaussian_window_1d(size, sigma)
    return torch.outer(g, g).to(dtype=dtype, device=device)


def _to_nchw(img: torch.Tensor) -> torch.Tensor:
    if img.dim() == 2:
        return img[None, None]
    if img.dim() == 3:
        return img.permute(2, 0, 1).unsqueeze(0)
    raise ValueError(f"expected an H x W or H x W x C image, got shape {tuple(img.shape)}")


@functools.lru_cache(maxsize=16)
def _window_on(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """The 1D window, made once per device (a copy to the GPU per call would make the host wait)."""
    return gaussian_window_1d(dtype=dtype, device=device)


def _blur(t: torch.Tensor) -> torch.Tensor:
    """The SSIM window applied to every channel of 1 x K x H x W, zero padded: rows, then columns."""
    k, pad = t.shape[1], SSIM_WINDOW // 2
    g = _window_on(t.dtype, t.device)
    t = F.conv2d(t, g.view(1, 1, 1, -1).expand(k, 1, 1, SSIM_WINDOW), padding=(0, pad), groups=k)
    return F.conv2d(t, g.view(1, 1, -1, 1).expand(k, 1, SSIM_WINDOW, 1), padding=(pad, 0), groups=k)


def ssim_map(img1: torch.Tensor, img2: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM, 1 x C x H x W (see module doc for the definition)."""
    if img1.shape != img2.shape:
        raise ValueError(f"ssim: shapes differ {tuple(img1.shape)} vs {tuple(img2.shape)}")
    x, y = _to_nchw(img1), _to_nchw(img2)
    # The five blurred images in one call.
    mu_x, mu_y, blur_xx, blur_yy, blur_xy = _blur(torch.cat([x, y, x * x, y * y, x * y], 1)).split(x.shape[1], 1)
    mu_xx, mu_yy, mu_xy = mu_x * mu_x, mu_y * mu_y, mu_x * mu_y
    sigma_xx, sigma_yy, sigma_xy = blur_xx - mu_xx, blur_yy - mu_yy, blur_xy - mu_xy
    return ((2 * mu_xy + SSIM_C1) * (2 * sigma_xy + SSIM_C2)) / (
        (mu_xx + mu_yy + SSIM_C1) * (sigma_xx + sigma_yy + SSIM_C2))
