"""Cameras: pose <-> quaternion, projection, constant-velocity prediction; `Intrinsics` (defined
in intrinsics.py, which needs no torch) is imported from here by the engine.

Conventions (docs/design.md, Conventions), stated once here:
- Camera axes are OpenCV: +x right, +y down, +z forward.
- Pixel centres sit at integer image coordinates: pixel (u, v) (column u, row v) is the point
  x = u, y = v, and a camera point (X, Y, Z) projects to (fx X/Z + cx, fy Y/Z + cy). So a
  depth pixel back-projected with `backproject` re-projects exactly onto itself.
- Quaternions are (w, x, y, z), Hamilton convention, scalar first.
- `w2c` maps world points into the camera; `c2w` is its inverse.
"""

from __future__ import annotations

import numpy as np
import torch

from .intrinsics import Intrinsics  # noqa: F401  (re-exported)


# ----------------------------------------------------------------------------- quaternions (torch)

def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) quaternions (w, x, y, z), not necessarily unit -> (..., 3, 3) rotation matrices."""
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(q.shape[:-1] + (3, 3))


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a * b of (..., 4) quaternions (w, x, y, z)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], dim=-1)


def w2c_from_quat_trans(q: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Differentiable 4x4 world-to-camera matrix from a quaternion (4,) and a translation (3,)."""
    top = torch.cat([quat_to_rotmat(q), t.reshape(3, 1)], dim=1)
    bottom = torch.zeros(1, 4, dtype=top.dtype, device=top.device)
    bottom[0, 3] = 1.0                  # a fill on the device: no host-to-device copy per call
    return torch.cat([top, bottom], dim=0)


# ----------------------------------------------------------------------------- quaternions (numpy)

def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """3x3 rotation matrix -> unit quaternion (w, x, y, z) with w >= 0 (numerically stable branch)."""
    R = np.asarray(R, dtype=np.float64)
    m = R
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def quat_to_rotmat_np(q) -> np.ndarray:
    """(w, x, y, z) -> 3x3 rotation matrix (numpy, float64)."""
    return quat_to_rotmat(torch.as_tensor(np.asarray(q, dtype=np.float64))).numpy()


def pose_matrix(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t).reshape(3)
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform (w2c <-> c2w) without a general matrix inverse."""
    R, t = T[:3, :3], T[:3, 3]
    return pose_matrix(R.T, -R.T @ t)


def invert_poses(Ts) -> np.ndarray:
    """invert_pose of n rigid 4x4 transforms of one dtype at once, (n, 4, 4) float64: the same
    numbers as one invert_pose per transform (computed in their dtype as it does;
    tests/core/test_camera.py), in one vectorised pass (a viewer asks for a whole trajectory
    after every frame)."""
    T = np.asarray(Ts).reshape(-1, 4, 4)
    Rt = T[:, :3, :3].transpose(0, 2, 1)
    out = np.zeros(T.shape, np.float64)
    out[:, :3, :3] = Rt
    out[:, :3, 3] = ((-Rt) @ T[:, :3, 3, None])[..., 0]      # as invert_pose: (-R^T) t, signed zeros too
    out[:, 3, 3] = 1.0
    return out


def is_finite_pose(T) -> bool:
    return T is not None and bool(np.all(np.isfinite(T)))


OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def c2w_opengl_to_opencv(c2w_gl: np.ndarray) -> np.ndarray:
    """Camera axes x right, y up, z backward (OpenGL/ARKit) -> OpenCV (docs/formats.md)."""
    return np.asarray(c2w_gl, dtype=np.float64) @ OPENGL_TO_OPENCV


# ----------------------------------------------------------------------------- pixels

def pixel_grid(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Integer pixel coordinates (u = column, v = row), each HxW float64."""
    return np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))


def backproject(depth: np.ndarray, intr: Intrinsics, mask: np.ndarray | None = None) -> np.ndarray:
    """HxW depth (metres) -> HxWx3 camera-space points at the pixel centres (see module doc); with an
    HxW bool `mask`, N x 3 at its pixels only, in row-major order (what [mask] of the HxWx3 gives)."""
    if mask is None:
        u, v = pixel_grid(intr.width, intr.height)
        z = depth.astype(np.float64)
    else:
        v, u = np.nonzero(mask)
        z = depth[v, u].astype(np.float64)
    return np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], axis=-1)


def project(points_cam: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """(..., 3) camera-space points -> (..., 2) pixel coordinates (u, v)."""
    z = points_cam[..., 2]
    return np.stack([intr.fx * points_cam[..., 0] / z + intr.cx,
                     intr.fy * points_cam[..., 1] / z + intr.cy], axis=-1)


# ----------------------------------------------------------------------------- motion model

def _skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _so3_jacobian(w: np.ndarray) -> np.ndarray:
    """V(w) of SE(3)'s exponential: t = V(w) u for the twist (w, u)."""
    W = _skew(w)
    _, b, c = _rodrigues(float(np.linalg.norm(w)))
    return np.eye(3) + b * W + c * W @ W


def _rodrigues(theta: float) -> tuple[float, float, float]:
    """sin(theta)/theta, (1 - cos(theta))/theta^2, (theta - sin(theta))/theta^3 (series near 0)."""
    if theta < 1e-3:
        t2 = theta * theta
        return 1.0 - t2 / 6.0, 0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0
    return np.sin(theta) / theta, (1.0 - np.cos(theta)) / theta ** 2, (theta - np.sin(theta)) / theta ** 3


def se3_log(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The twist (w, u) of a rigid 4x4 transform: T = se3_exp(w, u); w the rotation vector
    (angle below pi), u the translation part before V(w)."""
    R, t = T[:3, :3], T[:3, 3]
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    axis_sin = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2.0   # sin(theta) * axis
    theta = float(np.arctan2(np.linalg.norm(axis_sin), cos))
    if theta > np.pi - 1e-3:        # near half a turn sin(theta) vanishes: the axis from R's symmetric part
        aat = ((R + R.T) / 2.0 - cos * np.eye(3)) / (1.0 - cos)          # = a a^T
        k = int(np.argmax(np.diag(aat)))
        axis = aat[:, k] / np.sqrt(aat[k, k])
        w = theta * (axis if axis @ axis_sin >= 0 else -axis)
    else:
        w = axis_sin / _rodrigues(theta)[0]
    return w, np.linalg.solve(_so3_jacobian(w), t)


def se3_exp(w: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The rigid 4x4 transform of the twist (w, u) (Rodrigues for the rotation)."""
    W = _skew(w)
    a, b, _ = _rodrigues(float(np.linalg.norm(w)))
    return pose_matrix(np.eye(3) + a * W + b * W @ W, _so3_jacobian(w) @ u)


def scale_motion(delta: np.ndarray, ratio: float) -> np.ndarray:
    """delta^ratio: the rigid motion `delta` scaled along its screw (exp(ratio log delta)); a ratio
    of 1 returns delta itself, unchanged to the bit."""
    if ratio == 1.0:
        return delta
    w, u = se3_log(delta)
    return se3_exp(ratio * w, ratio * u)


def predict_constant_velocity(w2c_prev: np.ndarray, w2c_prev2: np.ndarray | None, ratio: float = 1.0) -> np.ndarray:
    """Predict the next w2c by applying the last relative motion again.

    The paper describes constant velocity of the camera; we apply the last frame-to-frame motion
    on SE(3) (T_t = T_{t-1} T_{t-2}^-1 T_{t-1}), which is exact for constant linear and angular
    velocity, instead of the original code's quaternion-sum extrapolation of w2c translations.

    `ratio`: the time from frame t-1 to t over the time from t-2 to t-1 (frames dropped by a
    real-time playback or a stream make the gaps uneven): the last motion is scaled by it in se(3)
    (delta^ratio), which keeps the prediction exact for a constant twist sampled at any times.
    A ratio of 1 (every frame processed) gives the unscaled prediction bit for bit.
    """
    if w2c_prev2 is None:
        return w2c_prev.copy()
    delta = w2c_prev @ invert_pose(w2c_prev2)
    return scale_motion(delta, ratio) @ w2c_prev
