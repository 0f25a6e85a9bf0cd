"""Camera paths through the synthetic room and its default camera (see scene.py for the world frame)."""

from __future__ import annotations

import numpy as np

from ..camera import Intrinsics


# ----------------------------------------------------------------------------- camera path

def look_at_c2w(eye, target, up=(0.0, -1.0, 0.0), roll: float = 0.0) -> np.ndarray:
    """c2w (OpenCV axes) of a camera at `eye` looking at `target`; `up` is the world up (-y here);
    `roll` (radians) rotates the camera about its viewing axis."""
    eye, target, up = (np.asarray(a, dtype=np.float64) for a in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)          # camera +x (right) = forward x up for y-down camera axes
    x /= np.linalg.norm(x)
    y = np.cross(z, x)           # camera +y points down
    R = np.stack([x, y, z], axis=1)
    c, s = np.cos(roll), np.sin(roll)
    R = R @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, eye
    return T


ORBIT_CENTRE = np.array([0.0, 0.6, 0.3])


def camera_path(n_frames: int, seed: int = 0, speed: float = 1.0) -> np.ndarray:
    """n_frames x 4 x 4 c2w poses of a smooth hand-held-like orbit around the objects.

    The path depends on the frame index only (not on n_frames); the seed picks the starting phase.
    `speed` scales the per-frame motion (1.0: ~1.5 cm and ~0.5-1 degree per frame).
    """
    rng = np.random.default_rng([seed, 7919])
    phase = rng.uniform(0, 2 * np.pi)
    wob = rng.uniform(0, 2 * np.pi, size=5)
    s = np.arange(n_frames, dtype=np.float64) * speed
    theta = phase + 0.0072 * s                       # ~1.45 cm/frame along a 2 m orbit
    radius = 2.0 + 0.25 * np.sin(0.021 * s + wob[0])
    height = -0.05 + 0.2 * np.sin(0.033 * s + wob[1])  # y (down): eye ~1.55 m above the floor
    eyes = np.stack([ORBIT_CENTRE[0] + radius * np.cos(theta), np.full_like(s, 0.0) + height,
                     ORBIT_CENTRE[2] + radius * np.sin(theta)], axis=1)
    targets = ORBIT_CENTRE + np.stack([0.35 * np.sin(0.045 * s + wob[2]),
                                       0.25 * np.sin(0.06 * s + wob[3]),
                                       0.35 * np.cos(0.04 * s + wob[4])], axis=1)
    roll = 0.1 * np.sin(0.05 * s + phase)
    return np.stack([look_at_c2w(e, t, roll=r) for e, t, r in zip(eyes, targets, roll)])


def default_intrinsics(width: int = 320, height: int = 240, fov_deg: float = 60.0) -> Intrinsics:
    """Square pixels, horizontal field of view `fov_deg`, principal point at the image centre
    (integer pixel centres: the centre is ((W-1)/2, (H-1)/2))."""
    f = 0.5 * width / np.tan(np.radians(fov_deg) / 2)
    return Intrinsics(f, f, (width - 1) / 2.0, (height - 1) / 2.0, int(width), int(height))
