"""Densification: which pixels get new Gaussians, and making them.

A pixel gets a Gaussian where the map does not explain it yet:
  - the silhouette is below 0.5 (nothing there), or
  - the map's depth lies behind the measured depth by more than 50x the median depth error
    (new geometry in front of the map),
and the measured depth is valid. New Gaussians sit on the back-projected pixel, with a one-pixel
radius (depth / mean focal length at the densification resolution) and opacity 0.5.
"""

from __future__ import annotations

import numpy as np
import torch

from .camera import Intrinsics, backproject, invert_pose
from .config import DensifyConfig
from .gaussians import GaussianMap


def new_pixel_mask(depth: np.ndarray, rendered_depth: np.ndarray, silhouette: np.ndarray,
                   config: DensifyConfig) -> np.ndarray:
    """H x W bool: pixels that need a new Gaussian (all inputs H x W numpy)."""
    valid = depth > 0
    empty = silhouette < config.silhouette_threshold
    error = np.abs(depth - rendered_depth) * valid
    # The median runs over all pixels, invalid ones (error 0) included, as in SplaTAM.
    median_error = float(np.median(error))
    in_front = (rendered_depth > depth) & (error > config.depth_error_factor * median_error)
    return (empty | in_front) & valid


def gaussians_from_pixels(color: np.ndarray, depth: np.ndarray, mask: np.ndarray, intr: Intrinsics,
                          w2c: np.ndarray, frame_index: int, config: DensifyConfig, isotropic: bool,
                          device="cpu", dtype=torch.float32) -> GaussianMap:
    """Back-project the masked pixels to new Gaussians in the world frame."""
    pts_cam = backproject(depth, intr)[mask]
    c2w = invert_pose(w2c)
    pts_world = pts_cam @ c2w[:3, :3].T + c2w[:3, 3]
    radii = depth[mask].astype(np.float64) / intr.mean_focal
    return GaussianMap.from_points(pts_world, color[mask], radii, frame_index, isotropic=isotropic,
                                   opacity=config.initial_opacity, device=device, dtype=dtype)
