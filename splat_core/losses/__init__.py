"""Image losses for tracking and mapping: masked L1 and SSIM (torch, differentiable).

Images are H x W x C (the renderer's colour layout) or H x W (depth, silhouette); any float
dtype and device. SSIM follows the standard 3D Gaussian splatting definition (Kerbl et al. 2023, as SplaTAM uses it): an
11 x 11 Gaussian window with sigma 1.5 applied per channel, zero padding of 5 pixels,
C1 = 0.01^2, C2 = 0.03^2 (data range 1), and the mean of the SSIM map. The window is the outer
product of a 1D Gaussian, so the blur runs as two 1D passes (same result, about twice as fast on
a CPU as one 11 x 11 convolution). On the CPU, `ssim` against a constant target runs Numba kernels
with an analytic backward (ssim_cpu.py); the torch code here is the reference and serves the rest.
"""

from __future__ import annotations

import torch

from ._torch_impl import (SSIM_C1, SSIM_C2, SSIM_SIGMA, SSIM_WINDOW, gaussian_window,  # noqa: F401
                          gaussian_window_1d, l1, ssim_map)


def ssim(img1: torch.Tensor, img2: torch.Tensor) -> torch.Tensor:
    """Mean SSIM of two H x W x C (or H x W) images: a 0-dim tensor, 1 for identical images.
    The mapping loss uses 1 - ssim(rendered, observed).

    CPU tensors of one float dtype (float32 or float64), H x W x C or H x W, with a target img2
    that needs no gradient take the Numba path (`ssim_cpu`: the same value and gradient, several
    times faster; benchmarks/ssim.py); anything else runs `ssim_map(img1, img2).mean()`."""
    if (img1.device.type == "cpu" and img2.device.type == "cpu"
            and img1.dtype in (torch.float32, torch.float64) and img2.dtype == img1.dtype
            and img1.dim() in (2, 3) and img1.shape == img2.shape and img1.numel() > 0
            and not img2.requires_grad):
        from .ssim_cpu import ssim_cpu
        return ssim_cpu(img1, img2)
    return ssim_map(img1, img2).mean()
