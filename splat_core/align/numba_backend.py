"""Direct alignment of a frame to the rendered map: a Gauss-Newton pose initialiser for tracking
(the Numba backend of `align/`; `torch_backend.py` is the same solve on the map's device).

SplaTAM tracks by running Adam on the pose for 40-200 iterations, each one a render and a
backward pass. A 2-core CPU affords about ten. Adam's steps have a fixed size (the learning
rate), so ten of them leave the pose about one step from the optimum: a centimetre of jitter
per frame, which becomes drift. This module removes that error cheaply. It renders the map
once at the predicted pose. Then it solves for the frame's pose against that rendering with
Gauss-Newton, the way dense RGB-D odometry does, but frame-to-model:

    live pixel u, depth -> point p = X V_live(u)   (X: live camera -> rendered camera, 6 DoF)
    u' = project(p)                                projective association, nearest pixel
    r_depth(u) = n(u') . (p - V_map(u'))           point-to-plane, n = rendered-depth normal
    r_color(u) = I_map(u') - I_live(u)             grey levels, I_map sampled bilinearly

Only rendered pixels with silhouette > `silhouette` are used, the same rule as the tracking
loss. Robust (Huber) weights apply. The solve runs coarse to fine over an image pyramid.
The map renders again at the solved pose for `passes` > 1, so a large motion is re-linearised.
The tracker (tracking.py) keeps the result only where SplaTAM's own tracking loss per pixel agrees
(lower than at the prediction), then polishes it with a few Adam iterations.

With `depth_noise`, each depth residual is divided by the sensor's axial noise at the live
point's depth, sigma(z) = 1.2 mm + 1.9 mm (z - 0.4 m)^2 (a Kinect v1 / structured-light model,
Nguyen, Izadi & Lovell 2012), relative to sigma(1 m): a residual at 3 m is divided by 7.5, one
at 0.5 m multiplied by 1.5, so the far, noisy half of a room no longer outvotes near surfaces.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from ..camera import Intrinsics, backproject, invert_pose
from ..frame import resize_to
from ..gaussians import Gaussians
from ..render import Render, render
from ..parallel import prefer_512_bit_vectors  # noqa: F401  (before the kernels: their vector width)


@dataclass
class AlignResult:
    w2c: np.ndarray
    correspondences: int        # depth residuals in the last iteration at full resolution
    rmse_depth: float           # their point-to-plane RMS (metres; relative to 1 m with depth_noise)
    first_render: Render        # the map rendered at w2c_init (the caller reuses it)
    first_pyramid: tuple | None = None  # that render's side of each pyramid level (model[2] for its reuse)


def _grey(color: np.ndarray) -> np.ndarray:
    return (color @ np.array([0.299, 0.587, 0.114])).astype(np.float64)


EXPOSURE_RANGE = (0.5, 2.0)     # the gain exposure_gain may return


def exposure_gain(live_grey, model_grey, mask) -> float:
    """One gain g so that g * model_grey matches live_grey's brightness on `mask` (the pixels the map
    explains and the frame has depth for): the ratio of their sums, clipped to EXPOSURE_RANGE; 1
    where fewer than 50 pixels or no brightness. Numpy or torch arrays (a Python float back)."""
    if int(mask.sum()) < 50:
        return 1.0
    live, model = float(live_grey[mask].sum()), float(model_grey[mask].sum())
    if not (live > 0 and model > 0):
        return 1.0
    return float(min(max(live / model, EXPOSURE_RANGE[0]), EXPOSURE_RANGE[1]))


def _se3_exp(xi: np.ndarray) -> np.ndarray:
    """Twist (v, w) -> 4x4 rigid transform."""
    v, w = xi[:3], xi[3:]
    theta = float(np.linalg.norm(w))
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if theta < 1e-10:
        R, V = np.eye(3) + K, np.eye(3) + 0.5 * K
    else:
        a, b = np.sin(theta) / theta, (1 - np.cos(theta)) / theta ** 2
        c = (1 - a) / theta ** 2
        R = np.eye(3) + a * K + b * K @ K
        V = np.eye(3) + b * K + c * K @ K
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, V @ v
    return T


def _normals(points: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normals of an HxWx3 vertex map by central differences; valid where all four neighbours are
    valid and the surface is not a depth discontinuity."""
    n = np.zeros_like(points)
    dx = points[1:-1, 2:] - points[1:-1, :-2]
    dy = points[2:, 1:-1] - points[:-2, 1:-1]
    c = np.cross(dx, dy)
    norm = np.linalg.norm(c, axis=-1)
    ok = valid[1:-1, 2:] & valid[1:-1, :-2] & valid[2:, 1:-1] & valid[:-2, 1:-1] & valid[1:-1, 1:-1]
    z = points[1:-1, 1:-1, 2]
    ok &= (norm > 0) & (np.abs(dx[..., 2]) < 0.1 * z) & (np.abs(dy[..., 2]) < 0.1 * z)
    inner = np.where(ok[..., None], c / np.maximum(norm, 1e-12)[..., None], 0.0)
    inner = np.where((np.sum(inner * points[1:-1, 1:-1], axis=-1) > 0)[..., None], -inner, inner)
    n[1:-1, 1:-1] = inner
    mask = np.zeros_like(valid)
    mask[1:-1, 1:-1] = ok
    return n, mask


class _ModelSide:
    """The rendered map's arrays of one pyramid level: the frames aligned against one reused render
    (tracking.align.reuse_render) share them."""

    def __init__(self, intr: Intrinsics, model_depth, model_grey, model_valid):
        self.model_points = backproject(np.where(model_valid, model_depth, 0.0), intr)
        self.model_normals, self.model_ok = _normals(self.model_points, model_valid)
        self.model_grey = model_grey
        gx = cv2.Sobel(model_grey, cv2.CV_64F, 1, 0, ksize=3) / 8.0
        gy = cv2.Sobel(model_grey, cv2.CV_64F, 0, 1, ksize=3) / 8.0
        self.model_grad = np.ascontiguousarray(np.stack([gx, gy], axis=-1))
        self.color_ok = cv2.erode(model_valid.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)


class _Level:
    """One pyramid level of the rendered model and the live frame."""

    def __init__(self, intr: Intrinsics, model_depth, model_grey, model_valid, live_depth, live_grey,
                 live_stride: int = 1, side: _ModelSide | None = None):
        """`side`: the model's arrays made already (model_depth, model_grey and model_valid unused)."""
        self.intr = intr
        self.side = _ModelSide(intr, model_depth, model_grey, model_valid) if side is None else side
        self.model_points, self.model_normals, self.model_ok = (self.side.model_points, self.side.model_normals,
                                                                self.side.model_ok)
        self.model_grey, self.model_grad, self.color_ok = self.side.model_grey, self.side.model_grad, self.side.color_ok
        live_valid = live_depth > 0
        if live_stride > 1:   # sparse tracking: every live_stride-th pixel in x and y
            grid = np.zeros_like(live_valid)
            grid[::live_stride, ::live_stride] = True
            live_valid &= grid
        self.live_points = backproject(live_depth, intr, live_valid)
        self.live_grey = np.ascontiguousarray(live_grey[live_valid])
        # tracking.align.depth_noise: residuals weighed by the sensor's noise at 1 m over its noise here
        self.noise_scale = _noise(1.0) / _noise(self.live_points[:, 2])
        self.ones = np.ones(len(self.live_points))


@numba.njit(cache=True, nogil=True)
def _linearise(live_points, live_grey, X, fx, fy, cx, cy, model_points, model_normals, model_ok,
               model_grey, model_grad, color_ok, max_distance):
    """Residuals and Jacobians (w.r.t. a left twist (v, w) on X) of every live point.

    Returns r_d, J_d, ok_d (point-to-plane) and r_c, J_c, ok_c (grey level)."""
    n = live_points.shape[0]
    height, width = model_ok.shape
    r_d, r_c = np.zeros(n), np.zeros(n)
    J_d, J_c = np.zeros((n, 6)), np.zeros((n, 6))
    ok_d, ok_c = np.zeros(n, np.bool_), np.zeros(n, np.bool_)
    for i in range(n):
        p = np.empty(3)
        for k in range(3):
            p[k] = (X[k, 0] * live_points[i, 0] + X[k, 1] * live_points[i, 1]
                    + X[k, 2] * live_points[i, 2] + X[k, 3])
        if p[2] <= 1e-3:
            continue
        u, v = fx * p[0] / p[2] + cx, fy * p[1] / p[2] + cy
        if not (u >= 0 and v >= 0 and u <= width - 2 and v <= height - 2):
            continue
        ui, vi = int(np.floor(u + 0.5)), int(np.floor(v + 0.5))
        if model_ok[vi, ui]:
            nx, ny, nz = model_normals[vi, ui, 0], model_normals[vi, ui, 1], model_normals[vi, ui, 2]
            r = (nx * (p[0] - model_points[vi, ui, 0]) + ny * (p[1] - model_points[vi, ui, 1])
                 + nz * (p[2] - model_points[vi, ui, 2]))
            if abs(r) < max_distance:
                r_d[i], ok_d[i] = r, True
                J_d[i, 0], J_d[i, 1], J_d[i, 2] = nx, ny, nz
                J_d[i, 3] = p[1] * nz - p[2] * ny
                J_d[i, 4] = p[2] * nx - p[0] * nz
                J_d[i, 5] = p[0] * ny - p[1] * nx
        u0, v0 = int(np.floor(u)), int(np.floor(v))
        if color_ok[v0, u0] and color_ok[v0, u0 + 1] and color_ok[v0 + 1, u0] and color_ok[v0 + 1, u0 + 1]:
            a, b = u - u0, v - v0
            w00, w01, w10, w11 = (1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b
            grey = (w00 * model_grey[v0, u0] + w01 * model_grey[v0, u0 + 1]
                    + w10 * model_grey[v0 + 1, u0] + w11 * model_grey[v0 + 1, u0 + 1])
            gx = (w00 * model_grad[v0, u0, 0] + w01 * model_grad[v0, u0 + 1, 0]
                  + w10 * model_grad[v0 + 1, u0, 0] + w11 * model_grad[v0 + 1, u0 + 1, 0])
            gy = (w00 * model_grad[v0, u0, 1] + w01 * model_grad[v0, u0 + 1, 1]
                  + w10 * model_grad[v0 + 1, u0, 1] + w11 * model_grad[v0 + 1, u0 + 1, 1])
            iz = 1.0 / p[2]
            dx, dy = gx * fx * iz, gy * fy * iz
            dz = -(gx * fx * p[0] + gy * fy * p[1]) * iz * iz
            r_c[i], ok_c[i] = grey - live_grey[i], True
            J_c[i, 0], J_c[i, 1], J_c[i, 2] = dx, dy, dz
            J_c[i, 3] = p[1] * dz - p[2] * dy
            J_c[i, 4] = p[2] * dx - p[0] * dz
            J_c[i, 5] = p[0] * dy - p[1] * dx
    return r_d, J_d, ok_d, r_c, J_c, ok_c


def _noise(z):
    """Axial depth noise (metres) of a structured-light sensor at depth z (Nguyen et al. 2012)."""
    return 0.0012 + 0.0019 * (z - 0.4) ** 2


@numba.njit(cache=True, nogil=True)
def _add_huber_system(r, J, ok, scale, floor, weight, H, g):
    """H += J^T W J and g += J^T W r over the rows with ok (r and J times scale[i]); W: Huber
    weights over a robust scale (1.4826 x the median |r|, at least floor) times weight / scale^2.
    Returns the sum of the rows' squared (scaled) residuals."""
    a = np.empty(r.shape[0])
    k = 0
    for i in range(r.shape[0]):
        if ok[i]:
            a[k] = abs(r[i] * scale[i])
            k += 1
    sigma = max(1.4826 * np.median(a[:k]), floor)
    squares = 0.0
    for i in range(r.shape[0]):
        if not ok[i]:
            continue
        ri = r[i] * scale[i]
        w = weight * min(1.0, 1.345 * sigma / max(abs(ri), 1e-12)) / (sigma * sigma) * scale[i] * scale[i]
        squares += ri * ri
        for p in range(6):
            wp = w * J[i, p]
            g[p] += wp * r[i]
            for q in range(p + 1):
                H[p, q] += wp * J[i, q]
    for p in range(6):
        for q in range(p):
            H[q, p] = H[p, q]
    return squares


def _gauss_newton_step(level: _Level, X: np.ndarray, color_weight: float, max_distance: float,
                       depth_noise: bool = False):
    """One weighted Gauss-Newton update of X (live camera -> model camera). Returns (dX, n, rmse)."""
    i = level.intr
    r_d, J_d, ok_d, r_c, J_c, ok_c = _linearise(
        level.live_points, level.live_grey, X, i.fx, i.fy, i.cx, i.cy, level.model_points,
        level.model_normals, level.model_ok, level.model_grey, level.model_grad, level.color_ok, max_distance)
    count = int(ok_d.sum())
    if count < 50:
        return np.eye(4), count, float("inf")
    H, g = np.zeros((6, 6)), np.zeros(6)
    squares = _add_huber_system(r_d, J_d, ok_d, level.noise_scale if depth_noise else level.ones, 1e-4, 1.0, H, g)
    if color_weight > 0 and ok_c.sum() >= 50:
        _add_huber_system(r_c, J_c, ok_c, level.ones, 1e-3, color_weight, H, g)
    H += 1e-6 * np.trace(H) / 6 * np.eye(6)
    return _se3_exp(-np.linalg.solve(H, g)), count, float(np.sqrt(squares / count))


def align_to_map(gaussians: Gaussians, color: np.ndarray, depth: np.ndarray, intr: Intrinsics,
                 w2c_init: np.ndarray, *, levels: int = 3, iterations: int = 10, passes: int = 1,
                 color_weight: float = 1.0, silhouette: float = 0.99, near: float = 0.01,
                 max_distance: float = 0.1, depth_noise: bool = False, live_stride: int = 1,
                 tolerance: float = 1e-7, model: tuple | None = None, exposure: bool = False) -> AlignResult:
    """Solve for the w2c of (colour HxWx3, depth HxW at `intr`) against the map rendered near w2c_init.

    live_stride > 1 uses every live_stride-th live pixel (in x and y) at the finest level only.
    A level stops when a step changes no entry of the pose by `tolerance` or more.

    model: (a Render of `gaussians`, the w2c it was rendered at[, its pyramid]) to align against in
    the first pass instead of rendering at w2c_init (tracking.align.reuse_render): the solve starts
    from w2c_init's pose relative to that render. Its pyramid (the first_pyramid of the AlignResult
    that made the render) spares remaking the render's side of every level; without `exposure`
    only, whose gain makes that side depend on the live frame.

    Falls back to w2c_init when the map explains too little of the frame (fewer than 50 residuals)."""
    w2c, correspondences, rmse = np.asarray(w2c_init, dtype=np.float64), 0, float("inf")
    live_grey = _grey(color)
    first = first_pyramid = None
    for p in range(passes):
        X0 = np.eye(4)
        pyramid = None
        if p == 0 and model is not None:
            out, w2c = model[0], np.asarray(model[1], dtype=np.float64)
            X0 = w2c @ invert_pose(np.asarray(w2c_init, dtype=np.float64))   # live camera -> rendered camera
            pyramid = None if exposure or len(model) < 3 else model[2]
        else:
            out = render(gaussians, intr, w2c, near=near)
        if pyramid is None:
            alpha = out.alpha.detach().cpu().numpy().astype(np.float64)
            valid = alpha > silhouette
            model_depth = np.where(valid, out.depth.detach().cpu().numpy() / np.maximum(alpha, 1e-6), 0.0)
            model_grey = _grey(out.color.detach().cpu().numpy().astype(np.float64))
            if exposure:
                model_grey = model_grey * exposure_gain(live_grey, model_grey, valid & (depth > 0))
        sides = [None] * levels
        X = X0
        for level in reversed(range(levels)):
            s = 0.5 ** level
            li = intr if level == 0 else intr.scaled(max(8, round(intr.width * s)), max(8, round(intr.height * s)))
            sides[level] = pyramid[level] if pyramid is not None else _ModelSide(
                li, resize_to(model_depth, li, True), resize_to(model_grey, li, False),
                resize_to(valid.astype(np.uint8), li, True).astype(bool))
            lvl = _Level(li, None, None, None, resize_to(depth.astype(np.float64), li, True),
                         resize_to(live_grey, li, False), live_stride if level == 0 else 1, side=sides[level])
            for _ in range(iterations):
                dX, correspondences, rmse = _gauss_newton_step(lvl, X, color_weight, max_distance, depth_noise)
                X = dX @ X
                if np.abs(dX - np.eye(4)).max() < tolerance:
                    break
        if first is None:
            first, first_pyramid = out, (None if exposure else tuple(sides))
        if correspondences < 50:
            return AlignResult(np.asarray(w2c_init, dtype=np.float64), correspondences, rmse, first, first_pyramid)
        # X maps live-camera points into the rendered camera: w2c_live = X^-1 w2c_rendered.
        w2c = invert_pose(X) @ w2c
    return AlignResult(w2c, correspondences, rmse, first, first_pyramid)
