"""Projection of 3D Gaussians to 2D screen-space Gaussians (EWA splatting).

Shared by the CPU and reference backends; the rasterizers only differentiate the compositing.
`project_gaussians_torch` is the definition, in torch autograd (gradients to means, scales,
rotations, opacities and the camera pose). `project_gaussians` runs isotropic Gaussians in CPU
tensors through project_cpu.py instead (one Numba kernel forward, one backward: the same values
and gradients, without ~100 small torch ops per call) and everything else through the torch code.
"""

from __future__ import annotations

import numpy as np
import torch

from ..camera import Intrinsics
from ..gaussians import Gaussians
from ._torch_impl import (Projected, clamp_limits, covariance_world, frustum_mask_torch,  # noqa: F401
                          project_gaussians_torch)


def project_gaussians(g: Gaussians, intr: Intrinsics, w2c: torch.Tensor, *,
                      near: float = 0.01, eps2d: float = 0.3) -> Projected:
    """Screen-space Gaussians for camera w2c (4 x 4). Isotropic Gaussians in CPU float32 / float64
    tensors go through the fused Numba kernels of project_cpu.py; everything else through
    `project_gaussians_torch` (the reference: both give the same values and gradients)."""
    from .project_cpu import project_isotropic_cpu, supported
    if supported(g, w2c):
        return project_isotropic_cpu(g, intr, w2c, near=near, eps2d=eps2d)
    return project_gaussians_torch(g, intr, w2c, near=near, eps2d=eps2d)


def frustum_mask(means: torch.Tensor, log_scales: torch.Tensor, intr: Intrinsics, w2c: np.ndarray,
                 near: float, margin: float = 0.1) -> torch.Tensor:
    """Gaussians whose 3.5-sigma footprint may touch the image (plus a margin); conservative.
    CPU tensors take project_cpu.frustum_mask_cpu (one Numba pass, float64; the same test)."""
    if means.device.type == "cpu" and means.dim() == 2 and len(means):
        from .project_cpu import frustum_mask_cpu
        return frustum_mask_cpu(means, log_scales, intr, w2c, near, margin)
    return frustum_mask_torch(means, log_scales, intr, w2c, near, margin)


