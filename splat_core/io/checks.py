"""Sanity checks on a capture: depth statistics and the pose-convention check of docs/formats.md.

Convention check: back-project frame i's depth, carry the points with the reference poses into
frame j = i + k, project, and compare the points' z with frame j's depth there. With the right
convention the median |dz| is centimetres; a wrong axis flip or a w2c/c2w mix-up gives
decimetres or more. The same points are also tried under the two usual mistakes (poses are
really w2c; camera axes are OpenGL) so the report can say which fix would help.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import OPENGL_TO_OPENCV, Intrinsics, invert_pose
from ..frame import Frame

CONVENTION_WARN_M = 0.05  # median |dz| above this suggests a convention problem
DEPTH_RANGE_OK_M = (0.1, 20.0)  # median depth outside this suggests wrong depth units


def reprojection_dz(frame_i: Frame, frame_j: Frame, c2w_i: np.ndarray, c2w_j: np.ndarray,
                    step: int = 4) -> np.ndarray:
    """|z of frame i's depth points seen from camera j - frame j's depth| at the pixels they hit.

    Pixels are subsampled every `step`; both frames must share intrinsics (one capture).
    Returns the absolute differences in metres (empty when nothing overlaps).
    """
    intr: Intrinsics = frame_i.intrinsics
    d = frame_i.depth[::step, ::step].astype(np.float64)
    v, u = np.mgrid[0:frame_i.height:step, 0:frame_i.width:step].astype(np.float64)
    ok = d > 0
    z = d[ok]
    pts = np.stack([(u[ok] - intr.cx) / intr.fx * z, (v[ok] - intr.cy) / intr.fy * z, z], axis=1)
    T = invert_pose(c2w_j) @ c2w_i  # camera i -> camera j
    pj = pts @ T[:3, :3].T + T[:3, 3]
    front = pj[:, 2] > 1e-3
    pj = pj[front]
    intr_j = frame_j.intrinsics
    uj = np.round(intr_j.fx * pj[:, 0] / pj[:, 2] + intr_j.cx).astype(np.int64)
    vj = np.round(intr_j.fy * pj[:, 1] / pj[:, 2] + intr_j.cy).astype(np.int64)
    inside = (uj >= 0) & (uj < frame_j.width) & (vj >= 0) & (vj < frame_j.height)
    dj = frame_j.depth[vj[inside], uj[inside]].astype(np.float64)
    valid = dj > 0
    return np.abs(pj[inside][valid, 2] - dj[valid])


@dataclass
class ConventionCheck:
    pairs: list[tuple[int, int]]
    median_abs_dz_m: float | None  # under the poses as read
    fraction_below_5cm: float | None
    n_points: int
    alternatives: dict[str, float | None] = field(default_factory=dict)  # "poses_are_w2c", "opengl_axes"
    ok: bool | None = None
    message: str = ""

    def to_dict(self) -> dict:
        return dict(pairs=[list(p) for p in self.pairs], median_abs_dz_m=self.median_abs_dz_m,
                    fraction_below_5cm=self.fraction_below_5cm, n_points=self.n_points,
                    alternatives=self.alternatives, ok=self.ok, message=self.message)


def choose_pairs(n: int, gap: int = 10, max_pairs: int = 4) -> list[tuple[int, int]]:
    """Frame pairs (i, i + k) spread over the sequence; k = min(gap, n - 1)."""
    if n < 2:
        return []
    k = max(1, min(gap, n - 1))
    starts = np.unique(np.linspace(0, n - 1 - k, num=min(max_pairs, n - k)).round().astype(int))
    return [(int(i), int(i) + k) for i in starts]


def convention_check(source, pairs: list[tuple[int, int]] | None = None, gap: int = 10,
                     max_pairs: int = 4, step: int = 4, warn_m: float = CONVENTION_WARN_M) -> ConventionCheck:
    """Run the reprojection test on `source` (a FrameSource with reference poses)."""
    if pairs is None:
        pairs = choose_pairs(len(source), gap, max_pairs)
    variants = {"as_read": lambda T: T, "poses_are_w2c": invert_pose, "opengl_axes": lambda T: T @ OPENGL_TO_OPENCV}
    dz = {name: [] for name in variants}
    used = []
    cache: dict[int, Frame] = {}
    for i, j in pairs:
        for k in (i, j):
            if k not in cache:
                cache[k] = source[k]
        fi, fj = cache[i], cache[j]
        if fi.c2w_ref is None or fj.c2w_ref is None:
            continue
        used.append((i, j))
        for name, fix in variants.items():
            dz[name].append(reprojection_dz(fi, fj, fix(fi.c2w_ref), fix(fj.c2w_ref), step))
    if not used:
        return ConventionCheck([], None, None, 0, ok=None, message="no frame pair with reference poses")
    med = {}
    for name in variants:
        allv = np.concatenate(dz[name]) if dz[name] else np.zeros(0)
        med[name] = float(np.median(allv)) if allv.size >= 20 else None
    main = np.concatenate(dz["as_read"])
    frac = float(np.mean(main < 0.05)) if main.size else None
    m = med["as_read"]
    check = ConventionCheck(used, m, frac, int(main.size),
                            {k: v for k, v in med.items() if k != "as_read"})
    if m is None:
        check.ok, check.message = None, "too little overlap between the checked frames"
    elif m <= warn_m:
        check.ok, check.message = True, f"poses and depth agree (median |dz| {m * 100:.1f} cm)"
    else:
        check.ok = False
        better = [k for k, v in check.alternatives.items() if v is not None and v < 0.5 * m and v <= warn_m]
        hint = {"poses_are_w2c": "the poses look like world-to-camera (inverted)",
                "opengl_axes": "the camera axes look like OpenGL (y up, z backward)"}
        check.message = (f"median |dz| {m * 100:.1f} cm between frames {used[0][0]} and {used[0][1]}: "
                         + (hint[better[0]] if better else
                            "wrong pose convention, depth units or intrinsics?"))
    return check


@dataclass
class DepthStats:
    frames: list[int]
    valid_fraction: float
    min_m: float | None
    median_m: float | None
    max_m: float | None
    units_ok: bool | None
    message: str = ""

    def to_dict(self) -> dict:
        return dict(frames=self.frames, valid_fraction=self.valid_fraction, min_m=self.min_m,
                    median_m=self.median_m, max_m=self.max_m, units_ok=self.units_ok, message=self.message)


def depth_stats(source, n_samples: int = 5) -> DepthStats:
    """Depth range and valid fraction over a few frames spread through the capture."""
    n = len(source)
    idx = sorted(set(np.linspace(0, n - 1, num=min(n_samples, n)).round().astype(int).tolist()))
    vals, total, valid = [], 0, 0
    for i in idx:
        d = source[i].depth
        total += d.size
        good = d[d > 0]
        valid += good.size
        vals.append(good[:: max(1, good.size // 20000)])
    allv = np.concatenate(vals) if vals else np.zeros(0)
    if allv.size == 0:
        return DepthStats(idx, 0.0, None, None, None, False, "no valid depth in the sampled frames")
    med = float(np.median(allv))
    lo, hi = DEPTH_RANGE_OK_M
    ok = lo <= med <= hi
    msg = "" if ok else (f"median depth {med:.3g} m is outside {lo}-{hi} m: wrong depth scale "
                         f"(millimetres vs metres?)")
    return DepthStats(idx, valid / total, float(allv.min()), med, float(allv.max()), ok, msg)


def trajectory_length(c2w: np.ndarray | None) -> float | None:
    """Sum of distances between consecutive valid camera centres."""
    if c2w is None:
        return None
    centres = np.asarray([T[:3, 3] for T in c2w if np.all(np.isfinite(T))])
    if len(centres) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum())


# ----------------------------------------------------------------------------- reference steps
#
# A reference trajectory can itself be wrong at a frame: 7-Scenes' KinectFusion poses jump 3.6 cm
# and 1.4 degrees between frames 121 and 122 of redkitchen while the two depth images barely
# differ. Every consecutive pair is reprojected with the reference's relative pose (the test
# above); a step whose residual stands far above its neighbours' is one the images contradict.

STEP_RATIO = 2.5        # median |dz| over the median of the neighbouring steps' medians,
STEP_INLIERS = 0.75     # fewer than this fraction of its points within 2 cm,
STEP_CONSISTENT = 0.9   # while its neighbours have at least this fraction (median over them)


def reference_step_residuals(source, step: int = 2) -> np.ndarray:
    """(N - 1) x 2: for each step i -> i + 1 of the reference poses, the median |dz| (metres) of
    frame i's depth reprojected into frame i + 1, and the fraction of points within 2 cm.
    NaN where a pose is missing or nothing overlaps."""
    ref = source.reference_c2w()
    if ref is None:
        raise ValueError("reference_step_residuals: the capture has no reference poses")
    out = np.full((max(len(source) - 1, 0), 2), np.nan)
    prev = source[0] if len(source) else None
    for i in range(1, len(source)):
        cur = source[i]
        if np.all(np.isfinite(ref[i - 1])) and np.all(np.isfinite(ref[i])):
            dz = reprojection_dz(prev, cur, ref[i - 1], ref[i], step)
            if dz.size:
                out[i - 1] = np.median(dz), np.mean(dz < 0.02)
        prev = cur
    return out


def inconsistent_steps(residuals: np.ndarray, window: int = 10, ratio: float = STEP_RATIO,
                       inliers: float = STEP_INLIERS, consistent: float = STEP_CONSISTENT) -> list[int]:
    """Steps i (reference pose i -> i + 1) that the depth images contradict inside an otherwise
    consistent stretch: median |dz| more than `ratio` times the median over the `window` steps
    either side, fewer than `inliers` of its points within 2 cm, and at least `consistent` within
    2 cm at its neighbours (median). A reference that is noisy throughout a stretch (SUN3D's
    bundle-adjusted poses: 40-75 % within 2 cm step after step) is jitter, not one wrong pose,
    and is not flagged."""
    med, frac = residuals[:, 0], residuals[:, 1]
    flagged = []
    for i in range(len(med)):
        if not np.isfinite(med[i]):
            continue
        near = np.r_[max(0, i - window):i, i + 1:min(len(med), i + window + 1)]
        near = near[np.isfinite(med[near])]
        if (near.size and med[i] > ratio * np.median(med[near]) and frac[i] < inliers
                and np.median(frac[near]) >= consistent):
            flagged.append(i)
    return flagged


def reference_breaks(source) -> list[int]:
    """`inconsistent_steps` of a capture's reference poses ([] when it has none)."""
    return inconsistent_steps(reference_step_residuals(source)) if source.has_reference_poses else []
