"""The map follows the corrected poses: each Gaussian is anchored to where it was born.

A keyframe's correction is the world-space rigid motion that takes its old pose to its optimised
one, C_k = c2w_k(new) c2w_k(old)^-1. A frame between keyframes k and k+1 (by frame number) gets the
correction interpolated between C_k and C_k+1 (translation linearly, rotation along the geodesic);
frames after the newest keyframe follow it; frames before the first follow it. A Gaussian's anchor
is its birth frame (GaussianMap.birth_frame, in the map and so in every checkpoint): it moves
rigidly with that frame's correction, its centre by C and its rotation by C's rotation. A frame's
pose moves the same way, so a Gaussian keeps its place in the view of the frame that made it.
"""

from __future__ import annotations

import numpy as np
import torch

from ..camera import invert_pose, quat_to_rotmat_np, rotmat_to_quat
from ..gaussians import GaussianMap


def corrections(old_c2ws: list[np.ndarray], new_c2ws: list[np.ndarray]) -> np.ndarray:
    """K x 4 x 4 world-space corrections, new c2w = C old c2w."""
    return np.stack([n @ invert_pose(o) for o, n in zip(old_c2ws, new_c2ws)])


def _slerp_rot(Ra: np.ndarray, Rb: np.ndarray, s: float) -> np.ndarray:
    q = rotmat_to_quat(Ra.T @ Rb)
    q = q if q[0] >= 0 else -q
    angle = 2.0 * np.arccos(np.clip(q[0], -1.0, 1.0))
    if angle < 1e-12:
        return Ra.copy()
    axis = q[1:] / np.linalg.norm(q[1:])
    return Ra @ quat_to_rotmat_np(np.r_[np.cos(s * angle / 2), np.sin(s * angle / 2) * axis])


def correction_at(frames: np.ndarray, keyframe_frames: np.ndarray, C: np.ndarray) -> np.ndarray:
    """N x 4 x 4 corrections of frame numbers `frames`, interpolated between the keyframes'."""
    frames = np.asarray(frames, np.int64)
    out = np.empty((len(frames), 4, 4))
    hi = np.searchsorted(keyframe_frames, frames, side="left")       # first keyframe at or after
    for n, (f, h) in enumerate(zip(frames, hi)):
        if h < len(keyframe_frames) and keyframe_frames[h] == f or h == 0:
            out[n] = C[min(h, len(C) - 1)]
        elif h >= len(keyframe_frames):
            out[n] = C[-1]
        else:
            fa, fb = keyframe_frames[h - 1], keyframe_frames[h]
            s = (f - fa) / (fb - fa)
            T = np.eye(4)
            T[:3, :3] = _slerp_rot(C[h - 1][:3, :3], C[h][:3, :3], s)
            T[:3, 3] = (1 - s) * C[h - 1][:3, 3] + s * C[h][:3, 3]
            out[n] = T
    return out


def move_gaussians(m: GaussianMap, keyframe_frames: np.ndarray, C: np.ndarray) -> None:
    """Move every Gaussian rigidly with its birth frame's correction (in place)."""
    if len(m) == 0:
        return
    birth = m.birth_frame.cpu().numpy()
    unique, inverse = np.unique(birth, return_inverse=True)
    per_frame = correction_at(unique, keyframe_frames, C)
    T = torch.as_tensor(per_frame[inverse], dtype=m.dtype, device=m.device)           # N x 4 x 4
    q_corr = torch.as_tensor(np.stack([rotmat_to_quat(t[:3, :3]) for t in per_frame])[inverse],
                             dtype=m.dtype, device=m.device)
    with torch.no_grad():
        means = m.params["means"].data
        means.copy_(torch.einsum("nij,nj->ni", T[:, :3, :3], means) + T[:, :3, 3])
        rot = m.params["rotations"].data
        rot.copy_(_quat_mul(q_corr, rot))


def _quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], dim=-1)


def move_poses(w2cs: list[np.ndarray], keyframe_frames: np.ndarray, C: np.ndarray, first: int = 0) -> None:
    """Correct frame poses w2cs[first:] in place (w2c' = w2c C^-1)."""
    frames = np.arange(first, len(w2cs))
    for f, T in zip(frames, correction_at(frames, keyframe_frames, C)):
        w2cs[f] = w2cs[f] @ invert_pose(T)
