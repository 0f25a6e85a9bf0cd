"""How well colour and depth line up, measured from a capture's own edges, and the colour camera
estimated from it (`splatam info --input X [--estimate-registration]`, docs/formats.md).

Edge agreement: at depth edges (half-way between 4-neighbours whose depths jump by more than
5 % + 3 cm, at the near depth) the colour image has an edge too when the two correspond. The figure is the mean colour-gradient
magnitude (Sobel of the grey image, blurred by a 1.5 px Gaussian) at the depth edges divided by its
mean over the whole image, averaged over a sample of frames: about 1 where colour and depth are
unrelated, higher the better they agree.

Estimation: the colour camera is modelled as the depth camera with its focal lengths scaled by r
(principal point kept, scaled to the colour image's size) and offset by t = (tx, ty, 0) with no
rotation; r, tx, ty are searched on a coarse-to-fine grid for the highest figure over ~10 frames'
depth-edge points sent into each frame's colour image.

Captures registered by their writer (a camera file that says `depth_registered_to_rgb: true`, the
TUM benchmark, ScanNet, ScanNet++, phone apps, Replica: `FrameSource.registered_by`) are not
estimated: `registered_by_writer` says why. On a moving capture the search can find the motion
between the colour and depth exposures instead of a calibration: on TUM fr1_xyz (Kinect v1, colour
and depth stamped 12-15 ms apart) it moves colour by ~15 px, and moving the depth points by the
reference poses' motion over 30-50 ms lines them up as well, after which the search finds the
identity (docs/benchmarks.md, "Two cameras"); a fixed offset cannot describe motion that changes
from frame to frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Intrinsics
from .registration import TwoCameras

EDGE_JUMP = (0.05, 0.03)         # relative, metres
MAX_EDGE_POINTS = 6000           # per frame
IDENTITY_PX = 3.0                # a best that moves no pixel more than this from the identity: registered
MIN_GAIN = 0.03                  # a best figure less than 3 % above the identity's is not an improvement
# coarse-to-fine: (focal ratio half-range, step), (tx half-range, step), (ty half-range, step), metres
STAGES = (((0.20, 0.02), (0.05, 0.005), (0.0, 1.0)),
          ((0.02, 0.004), (0.005, 0.001), (0.02, 0.004)),
          ((0.004, 0.001), (0.001, 0.00025), (0.004, 0.001)))


def gradient_map(color: np.ndarray) -> np.ndarray:
    """Blurred colour-gradient magnitude, divided by its image mean (HxW float32)."""
    import cv2

    grey = np.ascontiguousarray(color, dtype=np.float32).mean(axis=2)
    g = np.hypot(cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3))
    g = cv2.GaussianBlur(g, (0, 0), 1.5)
    m = float(g.mean())
    return (g / m if m > 0 else g).astype(np.float32)


def edge_points(depth: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depth edges as (u, v, z): half-way between the two pixels of a jump (where the silhouette's
    colour edge lies), at the near pixel's depth."""
    z = depth.astype(np.float32)
    us, vs, zs = [], [], []
    for (a, b), (du, dv) in (((np.s_[:, :-1], np.s_[:, 1:]), (0.5, 0.0)), ((np.s_[:-1, :], np.s_[1:, :]), (0.0, 0.5))):
        za, zb = z[a], z[b]
        near = np.minimum(za, zb)
        jump = (za > 0) & (zb > 0) & (np.abs(za - zb) > EDGE_JUMP[0] * near + EDGE_JUMP[1])
        v, u = np.nonzero(jump)
        us.append(u + du)
        vs.append(v + dv)
        zs.append(near[v, u])
    return np.concatenate(us), np.concatenate(vs), np.concatenate(zs).astype(np.float64)


def edge_mask(depth: np.ndarray) -> np.ndarray:
    """Near side of the depth jumps (both pixels valid)."""
    z = depth.astype(np.float32)
    edge = np.zeros(z.shape, dtype=bool)
    for a, b in ((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :])):
        za, zb = z[a], z[b]
        both = (za > 0) & (zb > 0)
        jump = np.abs(za - zb) > EDGE_JUMP[0] * np.minimum(za, zb) + EDGE_JUMP[1]
        edge[a] |= both & jump & (za < zb)
        edge[b] |= both & jump & (zb < za)
    return edge


@dataclass
class _Frames:
    """Depth-edge points of sampled frames and their colour-gradient maps, for fast scoring."""

    points: np.ndarray     # N x 3 depth-camera points (float64)
    frame: np.ndarray      # N frame numbers (into grads)
    grads: np.ndarray      # F x Hc x Wc
    color: Intrinsics      # the depth camera scaled to the colour images (the r = 1 colour camera)

    def score(self, r: float, tx: float, ty: float, ry: float | None = None, k: float = 0.0) -> float:
        """Edge agreement with the colour camera (r * focal, offset tx, ty; for
        benchmarks/focal_anisotropy.py: `ry` another ratio for the vertical focal, `k` a radial
        distortion of the colour camera relative to the depth camera's)."""
        F, h, w = self.grads.shape
        x, y, z = self.points[:, 0] + tx, self.points[:, 1] + ty, self.points[:, 2]
        if k:
            radial = 1 + k * (x * x + y * y) / (z * z)
            x, y = x * radial, y * radial
        u = r * self.color.fx * x / z + self.color.cx
        v = (r if ry is None else ry) * self.color.fy * y / z + self.color.cy
        ok = (u >= 0) & (v >= 0) & (u < w - 1) & (v < h - 1)
        if not ok.any():
            return 0.0
        u, v, f = u[ok], v[ok], self.frame[ok]
        u0, v0 = u.astype(np.int64), v.astype(np.int64)
        a, b = u - u0, v - v0
        flat = self.grads.reshape(-1)
        i = (f * h + v0) * w + u0
        val = ((1 - a) * (1 - b) * flat[i] + a * (1 - b) * flat[i + 1]
               + (1 - a) * b * flat[i + w] + a * b * flat[i + w + 1])
        per_frame = np.bincount(f, val, F) / np.maximum(np.bincount(f, None, F), 1)
        return float(per_frame[np.bincount(f, None, F) > 0].mean())


def sample_frames(n_total: int, n: int) -> list[int]:
    return sorted({int(round(k)) for k in np.linspace(0, n_total - 1, min(n, n_total))})


def gather_edges(pairs, depth_intr: Intrinsics, seed: int = 0) -> _Frames:
    """pairs: (colour as stored, depth on the grid of depth_intr)."""
    rng = np.random.default_rng(seed)
    pts, fr, grads = [], [], []
    for k, (color, depth) in enumerate(pairs):
        grads.append(gradient_map(color))
        us, vs, z = edge_points(depth)
        if len(us) > MAX_EDGE_POINTS:
            keep = rng.choice(len(us), MAX_EDGE_POINTS, replace=False)
            us, vs, z = us[keep], vs[keep], z[keep]
        pts.append(np.stack([(us - depth_intr.cx) / depth_intr.fx * z, (vs - depth_intr.cy) / depth_intr.fy * z, z], 1))
        fr.append(np.full(len(us), k, dtype=np.int64))
    h, w = grads[0].shape
    return _Frames(np.concatenate(pts), np.concatenate(fr), np.stack(grads), depth_intr.scaled(w, h))


def edge_agreement(source, n_frames: int = 10) -> float | None:
    """The figure over `n_frames` frames as the source yields them (registered, if it registers)."""
    frames = [source[i] for i in sample_frames(len(source), n_frames)]
    data = gather_edges([(f.color, f.depth) for f in frames], frames[0].intrinsics)
    return data.score(1.0, 0.0, 0.0) if len(data.points) else None


def _grid(centre: float, half: float, step: float) -> np.ndarray:
    n = int(round(half / step))
    return centre + step * np.arange(-n, n + 1)


def search(data: _Frames) -> tuple[float, float, float]:
    """(focal ratio, tx, ty) with the highest edge agreement, coarse to fine (STAGES)."""
    best = (1.0, 0.0, 0.0)
    for (rh, rs), (xh, xs), (yh, ys) in STAGES:
        cands = [(r, x, y) for r in _grid(best[0], rh, rs) for x in _grid(best[1], xh, xs)
                 for y in _grid(best[2], yh, ys)]
        scores = [data.score(*c) for c in cands]
        best = cands[int(np.argmax(scores))]
    return tuple(float(v) for v in best)


@dataclass
class Estimate:
    focal_ratio: float
    translation: tuple[float, float, float]
    before: float          # figure with colour taken as registered (identity)
    after: float           # figure with the estimate
    cameras: TwoCameras    # the colour camera found
    frames: list[int]
    shift_px: float        # the most the estimate moves a colour pixel from the identity (corners, median depth)

    @property
    def registered(self) -> bool:
        """The best is the identity within IDENTITY_PX pixels, or no better than it."""
        return bool(self.shift_px <= IDENTITY_PX or self.after < self.before * (1 + MIN_GAIN))


def estimate_registration(source, n_frames: int = 10) -> Estimate:
    """Search the colour focal ratio and offset (tx, ty) that best line colour up with depth,
    from `n_frames` frames' colour and depth as stored (a camera file's two cameras are ignored)."""
    ids = sample_frames(len(source), n_frames)
    pairs = [source.raw_pair(i) for i in ids]
    depth_intr = source.intrinsics.scaled(pairs[0][1].shape[1], pairs[0][1].shape[0])
    data = gather_edges(pairs, depth_intr)
    r, tx, ty = search(data)
    c = data.color
    cams = TwoCameras(Intrinsics(r * c.fx, r * c.fy, c.cx, c.cy, c.width, c.height), None, np.array([tx, ty, 0.0]))
    corner = np.hypot(max(c.cx, c.width - 1 - c.cx), max(c.cy, c.height - 1 - c.cy))
    shift = abs(r - 1) * corner + r * c.fx * np.hypot(tx, ty) / float(np.median(data.points[:, 2]))
    return Estimate(r, (tx, ty, 0.0), data.score(1.0, 0.0, 0.0), data.score(r, tx, ty), cams, ids, float(shift))


def registered_by_writer(source) -> str | None:
    """Why a capture is known to be registered without estimating it (its writer registered colour
    and depth, or its camera file says so), or None (estimate to find out)."""
    capture = getattr(source, "inner", source)          # --realtime playback: the capture it plays
    if getattr(capture, "two_cameras", None) is not None or not capture.registered:
        return None
    return getattr(capture, "registered_by", None)


def register_from_estimate(source, n_frames: int = 10) -> str | None:
    """For a capture whose camera file says colour and depth are not registered and names no colour
    camera: estimate one from the capture and register every frame with it (source.use_two_cameras).
    Returns the note to show, or None when the estimate finds nothing to correct (or the source
    cannot register: a stream). Deterministic (fixed frames, a grid search): a resumed run finds
    the same."""
    capture = getattr(source, "inner", source)          # --realtime playback: the capture it plays
    if getattr(capture, "live", False) or not hasattr(capture, "use_two_cameras") or len(capture) < 1:
        return None
    est = estimate_registration(capture, n_frames)
    if est.registered:
        return None
    capture.use_two_cameras(est.cameras)
    source.registered = True
    t = est.translation
    return (f"colour and depth are not registered (camera file) and no colour camera is given: estimated from the "
            f"capture (colour focal {est.cameras.color.fx:.1f}, offset {100 * t[0]:.2f}, {100 * t[1]:.2f} cm; edge "
            f"agreement {est.before:.2f} -> {est.after:.2f}) and registered; `splatam info --estimate-registration` "
            "prints the camera-file lines to fix it (docs/formats.md)")
