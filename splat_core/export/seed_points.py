"""Seed points for another trainer: the map's opaque Gaussian centres with their colours, thinned
to a sensible count, and where each one is seen (its track) in the exported frames.

Thinning keeps, in each cell of a regular grid (its size grown until at most `max_points` cells are
occupied), the most opaque Gaussian: every seed is an exact Gaussian centre. A point is seen in a
frame when it projects inside the image in front of the camera and the frame's depth at that pixel
agrees with its depth (within `max(abs_tol, rel_tol * depth)`), so occluded views are left out.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..camera import Intrinsics
from ..errors import InputError

MAX_POINTS = 100_000
MIN_OPACITY = 0.5


@dataclass
class Seeds:
    xyz: np.ndarray              # N x 3 float64 world (the run's frame)
    rgb: np.ndarray              # N x 3 uint8
    gaussian: np.ndarray         # N index into the map's arrays
    observations: list = field(default_factory=list)   # per frame: (point indices, u, v), our pixel convention


def seed_points(arrays: dict, max_points: int = MAX_POINTS, min_opacity: float = MIN_OPACITY) -> Seeds:
    """Opaque Gaussians (opacity >= min_opacity), one per grid cell, at most max_points."""
    if max_points < 1:
        raise InputError(f"--max-points {max_points}: expected a positive number of seed points")
    means = np.asarray(arrays["means"], np.float64)
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(arrays["logit_opacities"], np.float64).reshape(-1)))
    keep = np.flatnonzero((opacity >= min_opacity) & np.isfinite(means).all(1))
    if len(keep) == 0:
        raise InputError("the map has no opaque Gaussians to seed points from")
    if len(keep) > max_points:
        # Grow the cell from 1 mm until few enough cells are occupied (a surface map: the count
        # falls with the square of the cell, so the steps are small).
        pts = means[keep]
        lo, cell = pts.min(0), 0.001
        while True:
            cells = np.floor((pts - lo) / cell).astype(np.int64)
            key = (cells[:, 0] * 2_097_152 + cells[:, 1]) * 2_097_152 + cells[:, 2]
            order = np.lexsort((-opacity[keep], key))     # by cell, most opaque first
            first = np.ones(len(order), bool)
            first[1:] = key[order][1:] != key[order][:-1]
            if first.sum() <= max_points:
                keep = np.sort(keep[order[first]])
                break
            cell *= 1.15
    rgb = np.clip(np.round(np.asarray(arrays["colors"], np.float64)[keep] * 255.0), 0, 255).astype(np.uint8)
    return Seeds(means[keep], rgb, keep, [])


def project_points(xyz: np.ndarray, w2c: np.ndarray, intr: Intrinsics):
    """(u, v, z) of world points in a camera (camera.py's pixel convention: centres at integers)."""
    cam = xyz @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = intr.fx * cam[:, 0] / z + intr.cx
        v = intr.fy * cam[:, 1] / z + intr.cy
    return u, v, z


def add_observations(seeds: Seeds, w2c: np.ndarray, depth: np.ndarray, intr: Intrinsics,
                     abs_tol: float = 0.05, rel_tol: float = 0.05) -> np.ndarray:
    """Record which seeds the next frame sees, and where (appended to seeds.observations)."""
    u, v, z = project_points(seeds.xyz, w2c, intr)
    ui, vi = np.round(u), np.round(v)
    inside = (z > 0.01) & (ui >= 0) & (vi >= 0) & (ui <= intr.width - 1) & (vi <= intr.height - 1)
    idx = np.flatnonzero(inside)
    d = depth[vi[idx].astype(np.int64), ui[idx].astype(np.int64)]
    seen = idx[(d > 0) & (np.abs(z[idx] - d) <= np.maximum(abs_tol, rel_tol * d))]
    seeds.observations.append((seen, u[seen], v[seen]))
    return seen


def write_points_ply(path, xyz: np.ndarray, rgb: np.ndarray) -> None:
    """Binary PLY of coloured points (x y z float, red green blue uchar), as Open3D and nerfstudio read."""
    n = len(xyz)
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n").encode()
    rec = np.empty(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    rec["x"], rec["y"], rec["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rec["r"], rec["g"], rec["b"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    Path(path).write_bytes(header + rec.tobytes())
