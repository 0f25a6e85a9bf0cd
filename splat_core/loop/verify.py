"""Strict geometric verification of a loop candidate (a false loop is worse than none).

    1. ORB matches between the current keyframe and the old one (detect.py), each lifted to 3D
       with its own camera's depth; a 3D-3D RANSAC with the closed-form rigid fit (Kabsch) finds
       the current camera's pose in the old camera's frame. Enough inliers, and a large enough
       share of the matches, or no loop.
       Where RANSAC finds too little but the map says the old part is in view (detect.py's
       `visible`), the alignment starts from the tracked pose instead, and may move it by at most
       max_disagreement (the alignment's reach).
    2. The tracker's own alignment (align/: point-to-plane depth, Gauss-Newton, coarse to
       fine) of the current frame against the *old* part of the map (Gaussians born at least
       min_gap frames before), rendered from the pose RANSAC found. The old map must explain a
       large share of the frame's depth with a small residual, and the alignment must land where
       RANSAC did (two independent estimates agree), or no loop.
    3. The old keyframe's own measured depth (not the map) must agree with the current keyframe's
       depth at the aligned relative pose: min_depth_agreement of the current points that land on
       its valid depth within 2 cm + 1%.
The accepted measurement is the aligned pose relative to the old keyframe's pose, with its
evidence (inliers, overlap, residual, disagreement) kept for metrics.json and the checkpoint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..align import align_to_map
from ..camera import Intrinsics, invert_pose
from ..config import LoopClosureConfig
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
    """Camera-space points of the matched keypoints, and which have a trustworthy depth: the
    median of the 3x3 pixels around the keypoint, where they agree within 5% + 1 cm (a keypoint
    on a depth edge, common for corners, and in captures whose colour and depth are a few pixels
    off, gets no depth)."""
    uv = features.keypoints[pairs]
    h, w = depth.shape
    u = np.clip(np.rint(uv[:, 0]).astype(int), 1, w - 2)
    v = np.clip(np.rint(uv[:, 1]).astype(int), 1, h - 2)
    patch = np.stack([depth[v + dv, u + du] for dv in range(-1, 2) for du in range(-1, 2)], axis=1).astype(np.float64)
    z = np.median(patch, axis=1)
    ok = (patch.min(axis=1) > 0) & (patch.max(axis=1) - patch.min(axis=1) < 0.05 * z + 0.01)
    pts = np.stack([(uv[:, 0] - intr.cx) / intr.fx * z, (uv[:, 1] - intr.cy) / intr.fy * z, z], axis=1)
    return pts, ok


def depth_agreement(depth_a: np.ndarray, depth_b: np.ndarray, T_ab: np.ndarray, intr: Intrinsics,
                    stride: int = 4) -> tuple[float, int]:
    """(share, count): of camera a's depth points (every `stride`-th pixel) that land on valid depth
    inside camera b's image by T_ab (a -> b), the share whose depth b measured within 2 cm + 1% of
    the depth (a Kinect's noise at 3 m is about 2 cm)."""
    d = depth_a[::stride, ::stride].astype(np.float64)
    v, u = np.nonzero(d > 0)
    z = d[v, u]
    pts = np.stack([(u * stride - intr.cx) / intr.fx * z, (v * stride - intr.cy) / intr.fy * z, z], axis=1)
    p = pts @ T_ab[:3, :3].T + T_ab[:3, 3]
    front = p[:, 2] > 0.05
    p = p[front]
    ub = np.rint(intr.fx * p[:, 0] / p[:, 2] + intr.cx).astype(int)
    vb = np.rint(intr.fy * p[:, 1] / p[:, 2] + intr.cy).astype(int)
    inside = (ub >= 0) & (ub < depth_b.shape[1]) & (vb >= 0) & (vb < depth_b.shape[0])
    measured = depth_b[vb[inside], ub[inside]].astype(np.float64)
    valid = measured > 0
    count = int(valid.sum())
    if count == 0:
        return 0.0, 0
    agree = np.abs(measured[valid] - p[inside][valid, 2]) < 0.02 + 0.01 * measured[valid]
    return float(agree.mean()), count


def pose_difference(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(metres, degrees) between two 4x4 poses."""
    d = invert_pose(a) @ b
    cos = np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)
    return float(np.linalg.norm(d[:3, 3])), float(np.degrees(np.arccos(cos)))


def verify(current: tuple[Features, np.ndarray, np.ndarray], old: tuple[Features, np.ndarray, np.ndarray],
           c2w_old: np.ndarray, old_map: Gaussians, intr: Intrinsics, config: LoopClosureConfig,
           rng: np.random.Generator, align_kwargs: dict, c2w_estimate: np.ndarray | None = None) -> Verdict:
    """`current` / `old`: (ORB features, colour HxWx3 float, depth HxW) of the two keyframes;
    c2w_old: the old keyframe's pose (the frame of `old_map`); c2w_estimate: the current keyframe's
    tracked pose, the alignment's start when RANSAC finds too little (the map says the old part is
    in view, `visible`), in which case the correction may be at most `max_disagreement`."""
    (fa, color_a, depth_a), (fb, _, depth_b) = current, old
    pairs = match(fa, fb)
    ev: dict = dict(matches=int(len(pairs)))
    c2w_ransac = None
    if len(pairs) >= 3:
        pa, ok_a = lift(fa, pairs[:, 0], depth_a, intr)
        pb, ok_b = lift(fb, pairs[:, 1], depth_b, intr)
        ok = ok_a & ok_b
        pa, pb = pa[ok], pb[ok]
        T, inliers = ransac_rigid(pa, pb, config.inlier_distance, rng)      # current camera -> old camera
        n_in = int(inliers.sum())
        ev.update(matches_with_depth=int(ok.sum()), inliers=n_in, inlier_ratio=float(n_in / max(1, ok.sum())))
        if n_in >= config.min_inliers and ev["inlier_ratio"] >= config.min_inlier_ratio:
            spread = np.linalg.svd(pa[inliers] - pa[inliers].mean(0), compute_uv=False)
            ev["inlier_spread_m"] = float(spread[1] / np.sqrt(n_in))       # second axis: not a line
            if ev["inlier_spread_m"] >= 0.05:
                c2w_ransac = c2w_old @ T
    ev.setdefault("inliers", 0)
    if c2w_ransac is None and c2w_estimate is None:
        return Verdict(False, "inliers", ev)
    start = c2w_ransac if c2w_ransac is not None else c2w_estimate
    ev["route"] = "ransac" if c2w_ransac is not None else "map"
    aligned = align_to_map(old_map, color_a, depth_a, intr, invert_pose(start), **align_kwargs)
    stride = max(1, int(align_kwargs.get("live_stride", 1)))
    valid = max(1, int((depth_a[::stride, ::stride] > 0).sum()))
    c2w_aligned = invert_pose(aligned.w2c)
    dt, dr = pose_difference(start, c2w_aligned)
    agree, agree_count = depth_agreement(depth_a, depth_b, invert_pose(c2w_old) @ c2w_aligned, intr)
    ev.update(overlap=float(aligned.correspondences / valid), rmse_m=float(aligned.rmse_depth),
              start_vs_alignment_m=dt, start_vs_alignment_deg=dr, depth_agreement=agree,
              depth_agreement_points=agree_count)
    if ev["overlap"] < config.min_overlap:
        return Verdict(False, "overlap", ev)
    if not ev["rmse_m"] <= config.max_rmse:
        return Verdict(False, "residual", ev)
    if dt > config.max_disagreement or dr > config.max_disagreement_deg:
        return Verdict(False, "disagreement", ev)
    if agree < config.min_depth_agreement or agree_count < 200:
        return Verdict(False, "depth_agreement", ev)
    return Verdict(True, "accepted", ev, c2w_aligned)
