"""Test maps with known geometry (two walls) and their snapshots, for the viewer's tools."""

from __future__ import annotations

import numpy as np
from app.snapshot import MapSnapshot, freeze_gaussians
from splat_core.gaussians import GaussianMap
from splat_core.synthetic import look_at_c2w


A, B = np.array([-0.3, 0.1, 2.0]), np.array([0.3, -0.15, 1.5])   # on the wall and on the panel


def plane(x_range, y_range, z: float, spacing: float = 0.01) -> np.ndarray:
    xs = np.arange(x_range[0], x_range[1] + 1e-9, spacing)
    ys = np.arange(y_range[0], y_range[1] + 1e-9, spacing)
    gx, gy = np.meshgrid(xs, ys)
    return np.c_[gx.ravel(), gy.ravel(), np.full(gx.size, z)]


def two_walls() -> GaussianMap:
    """A wall at z = 2 m on the left and a panel at z = 1.5 m on the right, dense and opaque."""
    pts = np.r_[plane((-0.7, -0.05), (-0.4, 0.4), 2.0), plane((0.05, 0.6), (-0.3, 0.3), 1.5)]
    colors = np.where(pts[:, :1] < 0, [0.8, 0.3, 0.2], [0.2, 0.4, 0.9])
    return GaussianMap.from_points(pts, colors, np.full(len(pts), 0.008), 0, opacity=0.99)


def oblique_camera() -> np.ndarray:
    return look_at_c2w(np.array([0.25, -0.35, -0.4]), np.array([0.0, 0.0, 1.8]))


def ray_to(c2w: np.ndarray, point: np.ndarray) -> np.ndarray:
    d = point - c2w[:3, 3]
    return d / np.linalg.norm(d)


def snapshot_of(gmap: GaussianMap, version: int = 1) -> MapSnapshot:
    return MapSnapshot(version=version, state="browse", frame_index=0, total_frames=1, map_version=version,
                       gaussians=freeze_gaussians(gmap.to_numpy()))
