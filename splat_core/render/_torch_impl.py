"""The projection's definitions in torch autograd (the reference for project_cpu.py's kernels, and
the path for CUDA tensors and anisotropic Gaussians): EWA splatting of 3D Gaussians to screen-space
Gaussians, and the conservative frustum test. A leaf: the dispatcher (project.py) and the Numba
kernels (project_cpu.py) both import from here, never the other way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..camera import Intrinsics, quat_to_rotmat
from ..gaussians import Gaussians
from ._constants import RADIUS_SIGMAS


@dataclass
class Projected:
    """Screen-space Gaussians. Culled ones have radius 0 (their other values are finite but unused)."""

    means2d: torch.Tensor     # N x 2 pixel coordinates (u, v), centres at integers (camera.py)
    conics: torch.Tensor      # N x 3 inverse 2D covariance (a, b, c) of [[a, b], [b, c]]
    depths: torch.Tensor      # N camera-space z of the centre
    opacities: torch.Tensor   # N in (0, 1)
    radii: torch.Tensor       # N int32 footprint radius in pixels, 0 = culled


def covariance_world(g: Gaussians) -> torch.Tensor | None:
    """N x 3 x 3 world covariances for anisotropic Gaussians; None for isotropic (s^2 I)."""
    if g.isotropic:
        return None
    R = quat_to_rotmat(g.rotations)
    S = torch.exp(g.log_scales)
    M = R * S[:, None, :]
    return M @ M.transpose(1, 2)


def clamp_limits(intr: Intrinsics) -> tuple[float, float, float, float]:
    """(lim_x_neg, lim_x_pos, lim_y_neg, lim_y_pos): the Jacobian is evaluated with x/z clamped to
    [-lim_x_neg, lim_x_pos] and y/z to [-lim_y_neg, lim_y_pos], a margin around the frustum."""
    fx, fy, cx, cy = intr.fx, intr.fy, intr.cx, intr.cy
    return (cx / fx + 0.3 * intr.width / fx, (intr.width - cx) / fx + 0.3 * intr.width / fx,
            cy / fy + 0.3 * intr.height / fy, (intr.height - cy) / fy + 0.3 * intr.height / fy)


def project_gaussians_torch(g: Gaussians, intr: Intrinsics, w2c: torch.Tensor, *,
                            near: float = 0.01, eps2d: float = 0.3) -> Projected:
    R, t = w2c[:3, :3], w2c[:3, 3]
    p = g.means @ R.T + t                                   # camera-space centres
    x, y, z = p.unbind(-1)
    visible = z > near
    z_safe = torch.where(visible, z, torch.ones_like(z))
    fx, fy, cx, cy = intr.fx, intr.fy, intr.cx, intr.cy

    u = fx * x / z_safe + cx
    v = fy * y / z_safe + cy

    # The Jacobian is evaluated with x/z, y/z clamped to a margin around the frustum (as in 3DGS
    # and gsplat): Gaussians far outside the image otherwise get huge, meaningless footprints.
    lim_x_neg, lim_x_pos, lim_y_neg, lim_y_pos = clamp_limits(intr)
    tx = torch.clamp(x / z_safe, -lim_x_neg, lim_x_pos) * z_safe
    ty = torch.clamp(y / z_safe, -lim_y_neg, lim_y_pos) * z_safe
    zero = torch.zeros_like(z)
    J = torch.stack([
        fx / z_safe, zero, -fx * tx / (z_safe * z_safe),
        zero, fy / z_safe, -fy * ty / (z_safe * z_safe),
    ], dim=-1).reshape(-1, 2, 3)

    cov_w = covariance_world(g)
    if cov_w is None:
        # Isotropic: R s^2 I R^T = s^2 I, so the 2D covariance is s^2 J J^T.
        s2 = torch.exp(2.0 * g.log_scales[:, 0])
        cov2d = s2[:, None, None] * (J @ J.transpose(1, 2))
    else:
        cov_c = R @ cov_w @ R.T
        cov2d = J @ cov_c @ J.transpose(1, 2)

    a = cov2d[:, 0, 0] + eps2d                               # 0.3 px low-pass filter
    b = cov2d[:, 0, 1]
    c = cov2d[:, 1, 1] + eps2d
    det = a * c - b * b
    ok = visible & (det > 0)
    det_safe = torch.where(ok, det, torch.ones_like(det))
    conics = torch.stack([c / det_safe, -b / det_safe, a / det_safe], dim=-1)

    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam_max = mid + torch.sqrt(torch.clamp(mid * mid - det_safe, min=0.1))
        radii = torch.ceil(RADIUS_SIGMAS * torch.sqrt(lam_max))
        on_screen = ((u + radii > -0.5) & (u - radii < intr.width - 0.5)
                     & (v + radii > -0.5) & (v - radii < intr.height - 0.5))
        radii = torch.where(ok & on_screen, radii, torch.zeros_like(radii)).to(torch.int32)

    return Projected(
        means2d=torch.stack([u, v], dim=-1),
        conics=conics,
        depths=z,
        opacities=torch.sigmoid(g.logit_opacities),
        radii=radii,
    )


def frustum_mask_torch(means: torch.Tensor, log_scales: torch.Tensor, intr: Intrinsics, w2c: np.ndarray,
                       near: float, margin: float = 0.1) -> torch.Tensor:
    """`frustum_mask` in torch (the definition; CUDA)."""
    with torch.no_grad():
        R = torch.as_tensor(w2c[:3, :3], dtype=means.dtype, device=means.device)
        t = torch.as_tensor(w2c[:3, 3], dtype=means.dtype, device=means.device)
        p = means @ R.T + t
        z = p[:, 2]
        zs = torch.clamp(z, min=near)
        extent = 3.5 * torch.exp(log_scales).amax(dim=1)
        u = intr.fx * p[:, 0] / zs + intr.cx
        v = intr.fy * p[:, 1] / zs + intr.cy
        # Off-axis Gaussians project larger (perspective stretch), by at most this factor.
        stretch = torch.sqrt(1 + (p[:, 0] / zs) ** 2 + (p[:, 1] / zs) ** 2)
        r_px = extent * max(intr.fx, intr.fy) / zs * stretch + 2.0
        mx, my = margin * intr.width, margin * intr.height
        inside = ((u + r_px > -mx) & (u - r_px < intr.width + mx)
                  & (v + r_px > -my) & (v - r_px < intr.height + my))
        return (z + extent > near) & inside
