"""Direct alignment of a frame to the rendered map in torch: `numba_backend.py` on the map's device.

The same Gauss-Newton pose initialiser as the Numba version (point-to-plane depth + grey levels,
Huber weights, an image pyramid, `passes` renders), with the same numbers in float64: the pyramid
reproduces OpenCV's resizes (nearest, area averaging, bilinear), Sobel gradients (reflect-101
border) and erosion (no erosion at the border), and tests/align/test_direct_align_torch.py checks the
normal equations and the solved pose against the Numba version on CPU tensors (the OpenCV
operations in torch: cv_torch.py).

What differs is the shape of the work, so that a CUDA device never waits for the host inside the
solve:
- every live point is linearised at once (gathers) instead of in a loop;
- points the Numba version drops (no depth, out of view, no model normal, beyond max_distance)
  stay in the arrays with weight 0, so every tensor has a fixed shape (no boolean indexing,
  which needs the count on the host);
- the robust scale (a median) is taken by sorting with the dropped residuals at +inf and
  gathering at the count, on the device; "fewer than 50 residuals" and "converged" are device
  flags applied by torch.where: a converged level computes its remaining iterations and
  discards them, which costs less than asking the host whether to stop.
With `sync=True` (the default on the CPU, where asking is free) the loops stop early as the
Numba version does; the results are the same either way. The pose reaches the host once, at the
end.
"""

from __future__ import annotations

import numpy as np
import torch

from ..camera import Intrinsics
from ..render import render
from .cv_torch import _on, erode3, resize_nearest, resize_smooth, sobel  # noqa: F401 (the pyramid's operations)
from .numba_backend import AlignResult, exposure_gain

GREY = (0.299, 0.587, 0.114)


# ----------------------------------------------------------------------------- geometry

def grey(color: torch.Tensor) -> torch.Tensor:
    return color.to(torch.float64) @ _on(color.device, ("grey",), lambda: np.array(GREY, dtype=np.float64))


def backproject_t(depth: torch.Tensor, intr: Intrinsics) -> torch.Tensor:
    """camera.backproject in torch: H x W depth -> H x W x 3 points at the pixel centres."""
    h, w = depth.shape
    u = _on(depth.device, ("u", w), lambda: np.arange(w, dtype=np.float64))[None, :].expand(h, w)
    v = _on(depth.device, ("v", h), lambda: np.arange(h, dtype=np.float64))[:, None].expand(h, w)
    z = depth.to(torch.float64)
    return torch.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], dim=-1)


def normals(points: torch.Tensor, valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """numba_backend._normals in torch."""
    n = torch.zeros_like(points)
    dx = points[1:-1, 2:] - points[1:-1, :-2]
    dy = points[2:, 1:-1] - points[:-2, 1:-1]
    c = torch.linalg.cross(dx, dy, dim=-1)
    norm = torch.linalg.norm(c, dim=-1)
    ok = valid[1:-1, 2:] & valid[1:-1, :-2] & valid[2:, 1:-1] & valid[:-2, 1:-1] & valid[1:-1, 1:-1]
    z = points[1:-1, 1:-1, 2]
    ok = ok & (norm > 0) & (dx[..., 2].abs() < 0.1 * z) & (dy[..., 2].abs() < 0.1 * z)
    inner = torch.where(ok[..., None], c / torch.clamp(norm, min=1e-12)[..., None], 0.0)
    inner = torch.where(((inner * points[1:-1, 1:-1]).sum(-1) > 0)[..., None], -inner, inner)
    n[1:-1, 1:-1] = inner
    mask = torch.zeros_like(valid)
    mask[1:-1, 1:-1] = ok
    return n, mask


def se3_exp(xi: torch.Tensor) -> torch.Tensor:
    """numba_backend._se3_exp in torch (no branch on the host)."""
    v, w = xi[:3], xi[3:]
    theta = torch.linalg.norm(w)
    zero = torch.zeros_like(w[0])
    K = torch.stack([zero, -w[2], w[1], w[2], zero, -w[0], -w[1], w[0], zero]).reshape(3, 3)
    eye = torch.eye(3, dtype=xi.dtype, device=xi.device)
    small = theta < 1e-10
    th = torch.where(small, torch.ones_like(theta), theta)
    a, b = torch.sin(th) / th, (1 - torch.cos(th)) / th ** 2
    c = (1 - a) / th ** 2
    R = torch.where(small, eye + K, eye + a * K + (b * K) @ K)
    V = torch.where(small, eye + 0.5 * K, eye + b * K + (c * K) @ K)
    top = torch.cat([R, (V @ v)[:, None]], dim=1)
    return torch.cat([top, _on(xi.device, ("bottom",), lambda: np.array([[0.0, 0.0, 0.0, 1.0]])).to(xi.dtype)])


def invert_pose_t(T: torch.Tensor) -> torch.Tensor:
    R, t = T[:3, :3], T[:3, 3]
    top = torch.cat([R.T, (-R.T @ t)[:, None]], dim=1)
    return torch.cat([top, T[3:]], dim=0)


# ----------------------------------------------------------------------------- one pyramid level

class LevelT:
    """numba_backend._Level in torch: the model arrays of one level, and the live points as a fixed
    grid (every live_stride-th pixel) with a validity mask instead of the selected pixels."""

    def __init__(self, intr: Intrinsics, model_depth, model_grey, model_valid, live_depth, live_grey,
                 live_stride: int = 1):
        self.intr = intr
        self.model_points = backproject_t(torch.where(model_valid, model_depth, 0.0), intr)
        self.model_normals, self.model_ok = normals(self.model_points, model_valid)
        self.model_grey = model_grey
        gx, gy = sobel(model_grey)
        self.model_grad = torch.stack([gx / 8.0, gy / 8.0], dim=-1)
        self.color_ok = erode3(model_valid)
        self.set_live(live_depth, live_grey, live_stride)

    def set_live(self, live_depth, live_grey, live_stride: int = 1) -> None:
        s = live_stride
        points = backproject_t(live_depth, self.intr)[::s, ::s]
        self.live_points = points.reshape(-1, 3)
        self.live_valid = (live_depth[::s, ::s] > 0).reshape(-1)
        self.live_grey = live_grey[::s, ::s].reshape(-1)

    @classmethod
    def from_numpy(cls, level) -> "LevelT":
        """A torch level holding exactly a numba_backend._Level's arrays (tests)."""
        self = cls.__new__(cls)
        t = torch.as_tensor
        self.intr = level.intr
        self.model_points, self.model_normals = t(level.model_points), t(level.model_normals)
        self.model_ok, self.model_grey = t(level.model_ok), t(level.model_grey)
        self.model_grad, self.color_ok = t(level.model_grad), t(level.color_ok)
        self.live_points, self.live_grey = t(level.live_points), t(level.live_grey)
        self.live_valid = torch.ones(len(level.live_points), dtype=torch.bool)
        return self


def linearise(level: LevelT, X: torch.Tensor, max_distance: float):
    """numba_backend._linearise for every live point at once: (r_d, J_d, ok_d, r_c, J_c, ok_c),
    residuals and Jacobian rows zero where not ok."""
    i = level.intr
    height, width = level.model_ok.shape
    q = level.live_points
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    p0 = X[0, 0] * x + X[0, 1] * y + X[0, 2] * z + X[0, 3]
    p1 = X[1, 0] * x + X[1, 1] * y + X[1, 2] * z + X[1, 3]
    p2 = X[2, 0] * x + X[2, 1] * y + X[2, 2] * z + X[2, 3]
    front = level.live_valid & (p2 > 1e-3)
    z_safe = torch.where(front, p2, 1.0)
    u, v = i.fx * p0 / z_safe + i.cx, i.fy * p1 / z_safe + i.cy
    seen = front & (u >= 0) & (v >= 0) & (u <= width - 2) & (v <= height - 2)
    u, v = torch.where(seen, u, 0.0), torch.where(seen, v, 0.0)

    # point-to-plane at the nearest model pixel
    near = (torch.floor(v + 0.5).long() * width + torch.floor(u + 0.5).long())
    nrm = level.model_normals.reshape(-1, 3)[near]
    mp = level.model_points.reshape(-1, 3)[near]
    nx, ny, nz = nrm[:, 0], nrm[:, 1], nrm[:, 2]
    r = nx * (p0 - mp[:, 0]) + ny * (p1 - mp[:, 1]) + nz * (p2 - mp[:, 2])
    ok_d = seen & level.model_ok.reshape(-1)[near] & (r.abs() < max_distance)
    J_d = torch.stack([nx, ny, nz, p1 * nz - p2 * ny, p2 * nx - p0 * nz, p0 * ny - p1 * nx], dim=1)
    r_d = torch.where(ok_d, r, 0.0)
    J_d = torch.where(ok_d[:, None], J_d, 0.0)

    # grey level, bilinear at the projection
    u0, v0 = torch.floor(u), torch.floor(v)
    k00 = v0.long() * width + u0.long()
    corners = torch.stack([k00, k00 + 1, k00 + width, k00 + width + 1], dim=1)
    ok_c = seen & level.color_ok.reshape(-1)[corners].all(dim=1)
    a, b = u - u0, v - v0
    w = torch.stack([(1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b], dim=1)
    g = level.model_grey.reshape(-1)[corners]
    grad = level.model_grad.reshape(-1, 2)[corners]
    grey_at = (w * g).sum(1)
    gx, gy = (w * grad[..., 0]).sum(1), (w * grad[..., 1]).sum(1)
    iz = 1.0 / z_safe
    dx, dy = gx * i.fx * iz, gy * i.fy * iz
    dz = -(gx * i.fx * p0 + gy * i.fy * p1) * iz * iz
    J_c = torch.stack([dx, dy, dz, p1 * dz - p2 * dy, p2 * dx - p0 * dz, p0 * dy - p1 * dx], dim=1)
    r_c = torch.where(ok_c, grey_at - level.live_grey, 0.0)
    J_c = torch.where(ok_c[:, None], J_c, 0.0)
    return r_d, J_d, ok_d, r_c, J_c, ok_c


def _noise(z):
    return 0.0012 + 0.0019 * (z - 0.4) ** 2


def masked_median(values: torch.Tensor, ok: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
    """np.median(values[ok]) without boolean indexing (0 where nothing is ok)."""
    ordered = torch.sort(torch.where(ok, values, torch.inf)).values
    lo = torch.clamp((count - 1) // 2, min=0).reshape(1)
    hi = torch.clamp(count // 2, min=0).reshape(1)
    median = 0.5 * (ordered.index_select(0, lo) + ordered.index_select(0, hi))[0]
    return torch.where(count > 0, median, 0.0)


def huber_normal_equations(r, J, ok, count, floor: float, weight: float):
    """numba_backend._add_huber_system over the ok entries (the others weigh 0)."""
    absr = r.abs()
    sigma = torch.clamp(1.4826 * masked_median(absr, ok, count), min=floor)
    w = weight * torch.clamp(1.345 * sigma / torch.clamp(absr, min=1e-12), max=1.0) / sigma ** 2
    Jw = J * torch.where(ok, w, 0.0)[:, None]
    return Jw.T @ J, Jw.T @ r


def normal_equations(level: LevelT, X: torch.Tensor, color_weight: float, max_distance: float,
                     depth_noise: bool = False):
    """(H, g, depth residual count, depth rmse) of one Gauss-Newton step at X (as numba_backend)."""
    r_d, J_d, ok_d, r_c, J_c, ok_c = linearise(level, X, max_distance)
    if depth_noise:
        s = _noise(1.0) / _noise(level.live_points[:, 2])
        r_d, J_d = r_d * s, J_d * s[:, None]
    count = ok_d.sum()
    H, g = huber_normal_equations(r_d, J_d, ok_d, count, 1e-4, 1.0)
    if color_weight > 0:
        count_c = ok_c.sum()
        Hc, gc = huber_normal_equations(r_c, J_c, ok_c, count_c, 1e-3, color_weight)
        use = count_c >= 50
        H, g = H + torch.where(use, Hc, 0.0), g + torch.where(use, gc, 0.0)
    rmse = torch.sqrt((r_d ** 2).sum() / torch.clamp(count, min=1))
    return H, g, count, rmse


def gauss_newton_step(level: LevelT, X: torch.Tensor, color_weight: float, max_distance: float,
                      depth_noise: bool = False):
    """numba_backend._gauss_newton_step: (dX, count, rmse) as device tensors (identity, count, inf
    under 50 depth residuals)."""
    H, g, count, rmse = normal_equations(level, X, color_weight, max_distance, depth_noise)
    eye6 = torch.eye(6, dtype=H.dtype, device=H.device)
    H = H + 1e-6 * torch.trace(H) / 6 * eye6
    step = torch.linalg.solve_ex(H, g[:, None])[0][:, 0]
    enough = count >= 50
    dX = torch.where(enough, se3_exp(-torch.where(enough, step, 0.0)), torch.eye(4, dtype=H.dtype, device=H.device))
    return dX, count, torch.where(enough, rmse, torch.inf)


# ----------------------------------------------------------------------------- the alignment

def level_intrinsics(intr: Intrinsics, level: int) -> Intrinsics:
    s = 0.5 ** level
    return intr if level == 0 else intr.scaled(max(8, round(intr.width * s)), max(8, round(intr.height * s)))


def align_to_map_torch(gaussians, color, depth, intr: Intrinsics, w2c_init, *, levels: int = 3,
                       iterations: int = 10, passes: int = 1, color_weight: float = 1.0,
                       silhouette: float = 0.99, near: float = 0.01, max_distance: float = 0.1,
                       depth_noise: bool = False, live_stride: int = 1, tolerance: float = 1e-7,
                       sync: bool | None = None, exposure: bool = False) -> AlignResult:
    """numba_backend.align_to_map on the device of `gaussians` (colour H x W x 3 and depth H x W:
    numpy arrays or tensors). sync: let the host stop converged loops early (default: on the CPU)."""
    device = gaussians.means.device
    sync = device.type != "cuda" if sync is None else sync
    f64 = torch.float64
    as_t = lambda a: (a if torch.is_tensor(a) else torch.as_tensor(np.ascontiguousarray(a))).to(  # noqa: E731
        device, non_blocking=True)
    live_depth_full = as_t(depth).to(f64)
    live_grey_full = grey(as_t(color))
    eye4 = torch.eye(4, dtype=f64, device=device)
    init = as_t(np.asarray(w2c_init, dtype=np.float64)) if not torch.is_tensor(w2c_init) else w2c_init.to(device, f64)
    w2c = init
    # The live side of each level does not depend on the render: made once for every pass.
    lis = [level_intrinsics(intr, lv) for lv in range(levels)]
    live = [(resize_nearest(live_depth_full, li.height, li.width), resize_smooth(live_grey_full, li.height, li.width))
            for li in lis]
    correspondences = torch.zeros((), dtype=torch.long, device=device)
    rmse = torch.full((), torch.inf, dtype=f64, device=device)
    failed = torch.zeros((), dtype=torch.bool, device=device)
    out_corr, out_rmse = correspondences, rmse
    first = None
    for _ in range(passes):
        out = render(gaussians, intr, w2c.to(gaussians.means.dtype), near=near)
        first = out if first is None else first
        alpha = out.alpha.detach().to(f64)
        valid = alpha > silhouette
        model_depth = torch.where(valid, out.depth.detach().to(f64) / torch.clamp(alpha, min=1e-6), 0.0)
        model_grey = grey(out.color.detach())
        if exposure:    # one host synchronisation per render (the gain is a Python float)
            model_grey = model_grey * exposure_gain(live_grey_full, model_grey, valid & (live_depth_full > 0))
        X = eye4
        for lv in reversed(range(levels)):
            li = lis[lv]
            lvl = LevelT(li, resize_nearest(model_depth, li.height, li.width),
                         resize_smooth(model_grey, li.height, li.width),
                         resize_nearest(valid, li.height, li.width),
                         *live[lv], live_stride if lv == 0 else 1)
            done = torch.zeros((), dtype=torch.bool, device=device)
            for _ in range(iterations):
                dX, count, err = gauss_newton_step(lvl, X, color_weight, max_distance, depth_noise)
                X = torch.where(done, X, dX @ X)
                correspondences = torch.where(done, correspondences, count)
                rmse = torch.where(done, rmse, err)
                done = done | ((dX - eye4).abs().max() < tolerance)
                if sync and bool(done):
                    break
        newly = ~failed & (correspondences < 50)
        out_corr = torch.where(failed, out_corr, correspondences)
        out_rmse = torch.where(failed, out_rmse, rmse)
        failed = failed | newly
        # X maps live-camera points into the rendered camera: w2c_live = X^-1 w2c_rendered.
        w2c = torch.where(failed, init, invert_pose_t(X) @ w2c)
        if sync and bool(failed):
            break
    packed = torch.cat([w2c.reshape(-1), out_corr.to(f64).reshape(1), out_rmse.reshape(1)]).cpu().numpy()
    return AlignResult(packed[:16].reshape(4, 4).copy(), int(packed[16]), float(packed[17]), first)
