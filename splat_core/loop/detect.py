"""Loop candidates from our own data: the map's memory of where each Gaussian was born, and ORB.

Two independent signals name old keyframes that the current keyframe may see again:

    visible   the Gaussians born in an old keyframe's stretch of the run (birth_frame, anchors.py)
              that project into the current view in front of, and near, the depth the camera
              measures there: the map says "you are looking at what keyframe k made";
    orb       ORB descriptors (OpenCV, computed here: no vocabulary file, no weights) of the two
              keyframes' colour images matched with Lowe's ratio test: they look alike.

ORB matching is bounded per keyframe: the old keyframes the map names most (`orb_by_map`) and a few
others spread evenly over the run from a random offset (`orb_sample`), so its cost does not grow with
the run; a place the map does not recognise (drift too large) is still met by the sample within a
few keyframes of dwelling there, since neighbouring old keyframes look alike too.

Only keyframes at least `min_gap_frames` older than the current one count (recent keyframes see the
same things by continuity, not by returning). Candidates are ranked by the sum of their normalised
scores; verification (verify.py) is what accepts a loop, so this step may be generous.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..camera import Intrinsics, invert_pose

ORB_FEATURES = 1000
RATIO = 0.85


@dataclass
class Features:
    keypoints: np.ndarray         # N x 2 pixel coordinates (u, v)
    descriptors: np.ndarray       # N x 32 uint8 (empty: none)


def orb_features(color8: np.ndarray) -> Features:
    """ORB keypoints and descriptors of a uint8 HxWx3 image (deterministic for the same bytes)."""
    grey = cv2.cvtColor(np.ascontiguousarray(color8), cv2.COLOR_RGB2GRAY)
    orb = cv2.ORB_create(nfeatures=ORB_FEATURES, scaleFactor=1.2, nlevels=6, edgeThreshold=15, patchSize=15,
                         fastThreshold=10)
    kps, desc = orb.detectAndCompute(grey, None)
    if desc is None or not kps:
        return Features(np.zeros((0, 2)), np.zeros((0, 32), np.uint8))
    return Features(np.array([k.pt for k in kps], np.float64), desc)


def match(a: Features, b: Features, ratio: float = RATIO) -> np.ndarray:
    """M x 2 indices (into a, into b) of matches passing the ratio test and mutual best match."""
    if len(a.descriptors) < 2 or len(b.descriptors) < 2:
        return np.zeros((0, 2), np.int64)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    forward = bf.knnMatch(a.descriptors, b.descriptors, k=2)
    backward = {m[0].queryIdx: m[0].trainIdx for m in bf.knnMatch(b.descriptors, a.descriptors, k=1) if m}
    pairs = [(m[0].queryIdx, m[0].trainIdx) for m in forward
             if len(m) == 2 and m[0].distance < ratio * m[1].distance and backward.get(m[0].trainIdx) == m[0].queryIdx]
    return np.array(pairs, np.int64).reshape(-1, 2)


def birth_keyframe(birth_frame: np.ndarray, keyframe_frames: np.ndarray) -> np.ndarray:
    """Per Gaussian, the position (in the keyframe list) of the newest keyframe at or before its birth."""
    return np.clip(np.searchsorted(keyframe_frames, birth_frame, side="right") - 1, 0, None)


def visible_by_keyframe(means: np.ndarray, owner: np.ndarray, n_keyframes: int, depth: np.ndarray,
                        w2c: np.ndarray, intr: Intrinsics, tolerance: float = 0.15, stride: int = 2) -> np.ndarray:
    """Per keyframe, the fraction of the current view's valid depth pixels (on a grid of `stride`)
    that one of its Gaussians lands on within `tolerance` metres of the measured depth."""
    R, t = w2c[:3, :3], w2c[:3, 3]
    p = means @ R.T + t
    z = p[:, 2]
    front = z > 0.05
    p, z, owner = p[front], z[front], owner[front]
    u = np.floor(intr.fx * p[:, 0] / z + intr.cx + 0.5).astype(np.int64) // stride
    v = np.floor(intr.fy * p[:, 1] / z + intr.cy + 0.5).astype(np.int64) // stride
    d = depth[::stride, ::stride]
    h, w = d.shape
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    u, v, z, owner = u[inside], v[inside], z[inside], owner[inside]
    measured = d[v, u]
    near = (measured > 0) & (np.abs(z - measured) < tolerance)
    cells = v[near] * w + u[near]
    valid = max(1, int((d > 0).sum()))
    counts = np.zeros(n_keyframes)
    # a pixel counts once per keyframe however many of its Gaussians land there
    keys = np.unique(owner[near] * (h * w) + cells)
    np.add.at(counts, keys // (h * w), 1.0)
    return counts / valid


def orb_partners(old: np.ndarray, visible: np.ndarray, by_map: int, sample: int,
                 rng: np.random.Generator) -> np.ndarray:
    """Which old keyframe positions (`old`, ascending) to ORB-match: the `by_map` with the highest
    `visible` score, then `sample` of the rest at evenly spaced ranks from a random offset."""
    if old.size <= by_map + sample:
        return old
    order = np.argsort(-visible[old], kind="stable")
    named, rest = old[order[:by_map]], np.sort(old[order[by_map:]])
    picks = np.floor((np.arange(sample) + rng.random()) * (rest.size / max(sample, 1))).astype(np.int64)
    return np.sort(np.concatenate([named, rest[picks]]))


def candidates(current: int, keyframe_frames: np.ndarray, visible: np.ndarray, orb_matches: np.ndarray,
               min_gap: int, min_visible: float, min_orb: int, limit: int) -> list[int]:
    """Positions of old keyframes worth verifying, best first."""
    old = keyframe_frames <= keyframe_frames[current] - min_gap
    old[current] = False
    ok = old & ((visible >= min_visible) | (orb_matches >= min_orb))
    score = visible / max(min_visible, 1e-9) + orb_matches / max(min_orb, 1)
    order = [int(k) for k in np.argsort(-score, kind="stable") if ok[k]]
    return order[:limit]


def c2w_of(w2c: np.ndarray) -> np.ndarray:
    return invert_pose(np.asarray(w2c, np.float64))
