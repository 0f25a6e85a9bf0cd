"""The synthetic scene behind the capture fixtures, and what a reader must return for it.

A camera moving (and turning) in front of a textured back wall, a floor, a side wall and a
floating panel. Depth is analytic (ray/plane intersection at the pixel centres, camera.py's
convention), colour a smooth function of the hit point, poses exact (c2w, OpenCV axes).
`captures.py` writes sequences of it in each app's or toolkit's own layout.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from splat_core.camera import Intrinsics, pose_matrix

# Regions of every depth map (rows, cols) used to plant invalid values.
HOLE = (slice(0, 4), slice(0, 6))  # depth 0 in every format
MARK = (slice(4, 8), slice(0, 6))  # the format's own "invalid" marker (65535, NaN, low confidence)
MEDIUM = (slice(8, 12), slice(0, 6))  # confidence 1 (dropped by the default min_confidence=2)

PLANES = [  # (normal n, offset c): points x with n.x = c; optional bounds on the hit point
    (np.array([0.0, 0.0, 1.0]), 4.0, None),  # back wall z = 4
    (np.array([0.0, 1.0, 0.0]), 1.2, None),  # floor y = 1.2 (OpenCV: y down)
    (np.array([1.0, 0.0, 0.0]), -2.0, None),  # left wall x = -2
    (np.array([0.0, 0.0, 1.0]), 2.5, ((0.1, 1.0), (-0.8, 0.3))),  # panel z = 2.5, x and y bounds
]
COLOR_RENDER_PIXELS = 200_000  # larger colour images are rendered smaller and enlarged (smooth texture)


def _rot(yaw, pitch, roll):
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    Rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return Ry @ Rx @ Rz


def camera_path(n: int) -> list[np.ndarray]:
    out = []
    for i in range(n):
        s = i / max(n - 1, 1)
        t = [0.35 * np.sin(2.0 * s), -0.15 + 0.1 * np.cos(3.0 * s), 0.4 * s]
        R = _rot(np.radians(-8 + 16 * s), np.radians(4 * np.sin(3 * s)), np.radians(3 * s))
        out.append(pose_matrix(R, t))
    return out


def pixel_rays(intr: Intrinsics) -> np.ndarray:
    """HxWx3 camera-space ray directions (z = 1) through the pixel centres."""
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float64), np.arange(intr.height, dtype=np.float64))
    return np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], -1)


def render_rays(c2w: np.ndarray, d_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(colour HxWx3 float32 in [0,1], depth HxW float32 camera z) along rays with z = 1."""
    d = d_cam @ c2w[:3, :3].T
    o = c2w[:3, 3]
    best = np.full(d.shape[:2], np.inf)
    plane_id = np.zeros(d.shape[:2], dtype=int)
    for k, (n, c, bounds) in enumerate(PLANES):
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (c - o @ n) / (d @ n)
        ok = (s > 1e-6) & np.isfinite(s) & (s < best)
        if bounds is not None:
            x, y = o[0] + s * d[..., 0], o[1] + s * d[..., 1]
            ok &= (x > bounds[0][0]) & (x < bounds[0][1]) & (y > bounds[1][0]) & (y < bounds[1][1])
        best[ok] = s[ok]
        plane_id[ok] = k
    found = np.isfinite(best)
    hit = o + np.where(found, best, 0.0)[..., None] * d
    x, y, z = hit[..., 0], hit[..., 1], hit[..., 2]
    color = np.stack([
        0.5 + 0.35 * np.sin(2.2 * x + 1.3 * y + 0.7 * plane_id),
        0.5 + 0.35 * np.sin(1.7 * y - 1.1 * z + 1.9 * plane_id),
        0.5 + 0.35 * np.cos(1.5 * x + 1.2 * z - 0.5 * plane_id),
    ], -1)
    depth = np.where(found, best, 0.0)  # d_cam has z = 1, so s is the camera z
    return color.astype(np.float32), depth.astype(np.float32)


def render(c2w: np.ndarray, intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(colour, depth) seen by a pinhole camera c2w."""
    return render_rays(c2w, pixel_rays(intr))


def render_color(c2w: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Colour at intr's size; large images are rendered at fewer pixels and enlarged (bilinear)."""
    w, h = intr.width, intr.height
    if w * h <= COLOR_RENDER_PIXELS:
        return render(c2w, intr)[0]
    s = np.sqrt(COLOR_RENDER_PIXELS / (w * h))
    small = render(c2w, intr.scaled(int(round(w * s)), int(round(h * s))))[0]
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def make_intrinsics(width: int, height: int) -> Intrinsics:
    f = 0.85 * max(width, height)
    return Intrinsics(f, f * 1.01, (width - 1) / 2 + 0.7, (height - 1) / 2 - 0.4, width, height)


def jittered(intr: Intrinsics, i: int, amount: float) -> Intrinsics:
    """Frame i's camera when the focus (hence focal length and principal point) drifts, as ARKit's."""
    k = 1 + amount * np.sin(1.3 * i + 0.4)
    return Intrinsics(intr.fx * k, intr.fy * k, intr.cx + 40 * amount * np.cos(i), intr.cy - 30 * amount * np.sin(i),
                      intr.width, intr.height)


@dataclass
class Sequence:
    color_intr: Intrinsics  # the nominal colour camera
    depth_size: tuple[int, int]
    timestamps: np.ndarray
    c2w: list[np.ndarray]
    colors: list[np.ndarray]  # at the colour resolution
    depths: list[np.ndarray]  # at the depth resolution, 0 in HOLE
    frame_intr: list[Intrinsics] | None = None  # per-frame colour cameras, when they vary

    def color_intr_at(self, i: int) -> Intrinsics:
        return self.frame_intr[i] if self.frame_intr else self.color_intr

    def depth_intr_at(self, i: int) -> Intrinsics:
        intr = self.color_intr_at(i)
        w, h = self.depth_size
        return intr if (w, h) == (intr.width, intr.height) else intr.scaled(w, h)

    @property
    def depth_intr(self) -> Intrinsics:
        w, h = self.depth_size
        return self.color_intr if (w, h) == (self.color_intr.width, self.color_intr.height) else \
            self.color_intr.scaled(w, h)

    def __len__(self):
        return len(self.c2w)


def make_sequence(n: int = 8, color_size=(64, 48), depth_size=None, t0: float = 0.0, color_intr=None,
                  focal_jitter: float = 0.0, hole: bool = True, dt: float = 1 / 30.0) -> Sequence:
    cintr = color_intr or make_intrinsics(*color_size)
    depth_size = tuple(depth_size or (cintr.width, cintr.height))
    frame_intr = [jittered(cintr, i, focal_jitter) for i in range(n)] if focal_jitter else None
    seq = Sequence(cintr, depth_size, t0 + np.arange(n) * dt, camera_path(n), [], [], frame_intr)
    for i, T in enumerate(seq.c2w):
        seq.colors.append(render_color(T, seq.color_intr_at(i)))
        d = render(T, seq.depth_intr_at(i))[1]
        if hole:
            d[HOLE] = 0.0
        seq.depths.append(d)
    return seq


@dataclass
class Fixture:
    name: str
    path: Path
    seq: Sequence
    frames: list[int]  # sequence frames the reader should return, in order
    depth_tol: float  # quantisation of the format's depth
    color_tol: float  # mean |error| allowed for lossy colour
    marked: bool = True  # MARK region must read back as invalid
    medium_dropped: bool = False  # MEDIUM (confidence 1) must read back as invalid (default min_confidence=2)
    depth_exact: bool = True  # False: depth was resampled (fisheye undistortion), compare statistically
    poses: dict = field(default_factory=dict)  # sequence index -> expected c2w or None (default: seq.c2w)

    def expected(self, k: int):
        """(colour, depth, intrinsics, c2w) the reader must return for its k-th frame."""
        i = self.frames[k]
        intr = self.seq.depth_intr_at(i)
        color = self.seq.colors[i]
        if (color.shape[1], color.shape[0]) != (intr.width, intr.height):
            color = cv2.resize(color, (intr.width, intr.height), interpolation=cv2.INTER_AREA)
        depth = self.seq.depths[i].copy()
        if self.marked:
            depth[MARK] = 0.0
        if self.medium_dropped:
            depth[MEDIUM] = 0.0
        return color, depth, intr, self.poses.get(i, self.seq.c2w[i])
