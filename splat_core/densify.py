"""Densification: which pixels get new Gaussians, and making them.

A pixel gets a Gaussian where the map does not explain it yet:
  - the silhouette is below 0.5 (nothing there), or
  - the map's depth lies behind the measured depth by more than 50x the median depth error
    (new geometry in front of the map),
and the measured depth is valid. With densify.hole_fill > 0, pixels without valid depth where the
map is empty get one too, at the farthest valid depth within hole_fill x the image width
(`filled_depth`; farthest, as a depth shadow beside an edge belongs to the background): a screen
or a black, shiny patch the depth camera misses would otherwise stay black in every render.
New Gaussians sit on the back-projected pixel, with a one-pixel
radius (depth / mean focal length at the densification resolution) and opacity 0.5.
"""

from __future__ import annotations

import numpy as np
import torch

from .camera import Intrinsics, backproject, invert_pose
from .config import DensifyConfig
from .frame import resize_to
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


def filled_depth(depth: np.ndarray, fraction: float) -> np.ndarray:
    """depth with each invalid pixel set to the largest valid depth within round(fraction x width)
    pixels (a square window); 0 where none is that near (or fraction is 0)."""
    radius = int(round(fraction * depth.shape[1]))
    if radius <= 0:
        return np.where(depth > 0, depth, 0).astype(depth.dtype)
    import cv2
    valid = np.where(depth > 0, depth, 0).astype(np.float32)
    grown = cv2.dilate(valid, np.ones((2 * radius + 1, 2 * radius + 1), np.uint8), borderType=cv2.BORDER_CONSTANT,
                       borderValue=0)
    return np.where(depth > 0, depth, grown).astype(depth.dtype)


def hole_pixel_mask(depth: np.ndarray, filled: np.ndarray, silhouette: np.ndarray | None,
                    config: DensifyConfig) -> np.ndarray:
    """H x W bool: pixels without valid depth, with a filled depth, where the map is empty
    (silhouette None: an empty map)."""
    holes = (depth <= 0) & (filled > 0)
    return holes if silhouette is None else holes & (silhouette < config.silhouette_threshold)


def gaussians_from_pixels(color: np.ndarray, depth: np.ndarray, mask: np.ndarray, intr: Intrinsics,
                          w2c: np.ndarray, frame_index: int, config: DensifyConfig, isotropic: bool,
                          device="cpu", dtype=torch.float32) -> GaussianMap:
    """Back-project the masked pixels to new Gaussians in the world frame."""
    pts_cam = backproject(depth, intr, mask)
    c2w = invert_pose(w2c)
    pts_world = pts_cam @ c2w[:3, :3].T + c2w[:3, 3]
    radii = depth[mask].astype(np.float64) / intr.mean_focal
    return GaussianMap.from_points(pts_world, color[mask], radii, frame_index, isotropic=isotropic,
                                   opacity=config.initial_opacity, device=device, dtype=dtype)


def frame_gaussians(gmap: GaussianMap, renderer, intr: Intrinsics, color, depth, w2c, t: int, config,
                    device="cpu", dtype=torch.float32) -> GaussianMap:
    """The new Gaussians frame t adds at pose w2c (SplaTAM's densification, at `intr`): every pixel
    with depth for the first frame or an empty map, else where the map's render (`renderer`) leaves
    the pixel uncovered or sees new geometry in front (`new_pixel_mask`); with `densify.hole_fill`,
    also pixels without depth, at the farthest valid depth nearby; with `mapping.exposure`, colours
    brought to the map's exposure first. `config`: the run's Config. The caller appends them."""
    color_d, depth_d = resize_to(color, intr, False), resize_to(depth, intr, True)
    silhouette = None
    if t == 0 or len(gmap) == 0:
        mask = depth_d > 0
    else:
        with torch.no_grad():
            out = renderer.render_visible(gmap, intr, w2c)
        silhouette = out.alpha.cpu().numpy()
        mask = new_pixel_mask(depth_d, out.depth.cpu().numpy(), silhouette, config.densify)
        if config.mapping.exposure:
            color_d = unexposed(color_d, out, config.mapping.exposure_prior)
    if config.densify.hole_fill > 0:
        filled = filled_depth(depth_d, config.densify.hole_fill)
        mask = mask | hole_pixel_mask(depth_d, filled, silhouette, config.densify)
        depth_d = filled
    return gaussians_from_pixels(color_d, depth_d, mask, intr, w2c, t, config.densify, config.isotropic,
                                 device=device, dtype=dtype)


def unexposed(color: np.ndarray, rendered, prior: float) -> np.ndarray:
    """The frame's colours brought to the map's exposure (mapping.exposure): the inverse of the
    frame's gain and offset fitted against the map's render where it covers the frame, so new
    Gaussians start at the exposure the map keeps."""
    from .mapping import exposure_fit

    observed = torch.as_tensor(color, dtype=rendered.color.dtype, device=rendered.color.device)
    covered = rendered.alpha.reshape(observed.shape[:2]) > 0.5
    gain, offset = exposure_fit(rendered.color, observed, covered, prior)
    return ((observed - offset) / gain.clamp(min=0.1)).clamp(0, 1).cpu().numpy().astype(color.dtype)
