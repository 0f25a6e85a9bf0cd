"""Strict geometric verification of a loop candidate (a false loop is worse than none).

    1. ORB matches between the current keyframe and the old one (detect.py), each lifted to 3D
       with its own camera's depth; a 3D-3D RANSAC with the closed-form rigid fit (Kabsch) finds
       the current camera's pose in the old camera's frame. Enough inliers, and a large enough
       share of the matches, or no loop.
    2. The tracker's own alignment (direct_align.py: point-to-plane depth, Gauss-Newton, coarse to
       fine) of the current frame against the *old* part of the map (Gaussians born at least
       min_gap frames before), rendered from the pose RANSAC found. The old map must explain a
       large share of the frame's depth with a small residual, and the alignment must land where
       RANSAC did (two independent estimates agree), or no loop.
The accepted measurement is the aligned pose relative to the old keyframe's pose, with its
evidence (inliers, overlap, residual, disagreement) kept for metrics.json and the checkpoint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Intrinsics, invert_pose
from ..config import LoopClosureConfig
from ..direct_align import align_to_map
from ..gaussians import Gaussians
from .detect import Features, match


@dataclass
class Verdict:
    accepted: bool
    reason: str                   # accepted, or the test that failed: matches, inliers, line, overlap, residual, disagreement
    evidence: dict
    c2w_current: np.ndarray | None = None      # the current keyframe's pose in the old map's world


def rigid_fit(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """4x4 T minimising sum |T a_i - b_i|^2 (Kabsch, no scale); a, b: N x 3."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    H = (a - ca).T @ (b - cb)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, cb - R @ ca
    return T


def ransac_rigid(a: np.ndarray, b: np.ndarray, threshold: float, rng: np.random.Generator,
                 iterations: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """(T with b ~ T a, inlier mask) by RANSAC over 3-point samples, refit on the inliers."""
    n = len(a)
    best = np.zeros(n, bool)
    if n < 3:
        return np.eye(4), best
    for _ in range(iterations):
        pick = rng.choice(n, 3, replace=False)
        if np.linalg.matrix_rank(a[pick] - a[pick].mean(0), tol=1e-3) < 2:
            continue
        T = rigid_fit(a[pick], b[pick])
        inl = np.linalg.norm(a @ T[:3, :3].T + T[:3, 3] - b, axis=1) < threshold
        if inl.sum() > best.sum():
            best = inl
    if best.sum() < 3:
        return np.eye(4), best
    for _ in range(2):                  # refit on the inliers, then re-score
        T = rigid_fit(a[best], b[best])
        best = np.linalg.norm(a @ T[:3, :3].T + T[:3, 3] - b, axis=1) < threshold
        if best.sum() < 3:
            return np.eye(4), best
    return T, best


def lift(features: Features, pairs: np.ndarray, depth: np.ndarray, intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Camera-space points of the matched keypoints, and which have a valid depth."""
    uv = features.keypoints[pairs]
    u = np.clip(np.rint(uv[:, 0]).astype(int), 0, depth.shape[1] - 1)
    v = np.clip(np.rint(uv[:, 1]).astype(int), 0, depth.shape[0] - 1)
    z = depth[v, u].astype(np.float64)
    pts = np.stack([(uv[:, 0] - intr.cx) / intr.fx * z, (uv[:, 1] - intr.cy) / intr.fy * z, z], axis=1)
    return pts, z > 0


def pose_difference(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(metres, degrees) between two 4x4 poses."""
    d = invert_pose(a) @ b
    cos = np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)
    return float(np.linalg.norm(d[:3, 3])), float(np.degrees(np.arccos(cos)))


def verify(current: tuple[Features, np.ndarray, np.ndarray], old: tuple[Features, np.ndarray, np.ndarray],
           c2w_old: np.ndarray, old_map: Gaussians, intr: Intrinsics, config: LoopClosureConfig,
           rng: np.random.Generator, align_kwargs: dict) -> Verdict:
    """`current` / `old`: (ORB features, colour HxWx3 float, depth HxW) of the two keyframes;
    c2w_old: the old keyframe's pose (the frame of `old_map`)."""
    (fa, color_a, depth_a), (fb, _, depth_b) = current, old
    pairs = match(fa, fb)
    ev: dict = dict(matches=int(len(pairs)))
    if len(pairs) < config.min_inliers:
        return Verdict(False, "matches", ev)
    pa, ok_a = lift(fa, pairs[:, 0], depth_a, intr)
    pb, ok_b = lift(fb, pairs[:, 1], depth_b, intr)
    ok = ok_a & ok_b
    pa, pb = pa[ok], pb[ok]
    T, inliers = ransac_rigid(pa, pb, config.inlier_distance, rng)      # current camera -> old camera
    n_in = int(inliers.sum())
    ev.update(matches_with_depth=int(ok.sum()), inliers=n_in,
              inlier_ratio=float(n_in / max(1, ok.sum())))
    if n_in < config.min_inliers or ev["inlier_ratio"] < config.min_inlier_ratio:
        return Verdict(False, "inliers", ev)
    spread = np.linalg.svd(pa[inliers] - pa[inliers].mean(0), compute_uv=False)
    ev["inlier_spread_m"] = float(spread[1] / np.sqrt(n_in))           # second axis: not a line
    if ev["inlier_spread_m"] < 0.05:
        return Verdict(False, "line", ev)
    c2w_ransac = c2w_old @ T
    aligned = align_to_map(old_map, color_a, depth_a, intr, invert_pose(c2w_ransac), **align_kwargs)
    stride = max(1, int(align_kwargs.get("live_stride", 1)))
    valid = max(1, int((depth_a[::stride, ::stride] > 0).sum()))
    c2w_aligned = invert_pose(aligned.w2c)
    dt, dr = pose_difference(c2w_ransac, c2w_aligned)
    ev.update(overlap=float(aligned.correspondences / valid), rmse_m=float(aligned.rmse_depth),
              ransac_vs_alignment_m=dt, ransac_vs_alignment_deg=dr)
    if ev["overlap"] < config.min_overlap:
        return Verdict(False, "overlap", ev)
    if not ev["rmse_m"] <= config.max_rmse:
        return Verdict(False, "residual", ev)
    if dt > config.max_disagreement or dr > config.max_disagreement_deg:
        return Verdict(False, "disagreement", ev)
    return Verdict(True, "accepted", ev, c2w_aligned)
