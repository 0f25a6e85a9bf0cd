"""Densification (densify.py): new Gaussians only where the map is empty or behind, on back-projected pixels."""

from __future__ import annotations

import numpy as np
import torch

from splat_core.camera import (invert_pose, pose_matrix, project, quat_to_rotmat_np)
from splat_core.config import DensifyConfig
from splat_core.densify import gaussians_from_pixels, new_pixel_mask

from helpers.engine import small_source


def test_densify_adds_only_where_the_map_is_empty_or_behind():
    h, w = 30, 40
    depth = np.full((h, w), 2.0, np.float32)
    rendered = np.full((h, w), 2.0, np.float32)
    sil = np.ones((h, w), np.float32)
    sil[:, :10] = 0.2                      # empty map on the left
    rendered[:5, 20:30] = 3.0              # map behind the measurement: new geometry in front
    rendered[25:, 20:30] = 1.0             # map in front of the measurement: not densified
    depth[10:12, 30:] = 0.0                # invalid depth never densified
    sil[10:12, 30:] = 0.0
    depth_noise = depth + np.random.default_rng(0).normal(0, 1e-4, depth.shape).astype(np.float32) * (depth > 0)
    mask = new_pixel_mask(depth_noise, rendered, sil, DensifyConfig())
    expected = np.zeros((h, w), bool)
    expected[:, :10] = True
    expected[:5, 20:30] = True
    assert np.array_equal(mask, expected)


def test_new_gaussians_sit_on_back_projected_pixels_with_one_pixel_radius():
    src = small_source(n=1, w=40, h=30)
    f = src[0]
    c2w = pose_matrix(quat_to_rotmat_np([0.98, 0.1, 0.05, -0.1]), [0.2, -0.1, 0.3])
    mask = f.depth > 0
    g = gaussians_from_pixels(f.color, f.depth, mask, f.intrinsics, invert_pose(c2w), 7, DensifyConfig(), True)
    assert len(g) == mask.sum() and set(g.birth_frame.tolist()) == {7}
    pts_cam = (g.means.detach().double().numpy() - c2w[:3, 3]) @ c2w[:3, :3]
    uv = project(pts_cam, f.intrinsics)
    v, u = np.nonzero(mask)
    assert np.allclose(uv, np.stack([u, v], 1), atol=1e-3)
    radii = torch.exp(g.log_scales[:, 0]).detach().numpy()
    assert np.allclose(radii, f.depth[mask] / f.intrinsics.mean_focal, rtol=1e-5)
    assert np.allclose(torch.sigmoid(g.logit_opacities).detach().numpy(), 0.5)


def test_filled_depth_takes_the_farthest_valid_depth_within_the_radius_and_leaves_valid_depth():
    from splat_core.densify import filled_depth
    depth = np.zeros((20, 40), np.float32)
    depth[:, :10] = 1.0                      # near surface on the left
    depth[:, 14:] = 3.0                      # far one on the right; columns 10-13: a depth shadow
    depth[5:8, 30:34] = 0                    # a hole inside the far surface
    out = filled_depth(depth, 0.1)           # radius 4 px
    assert np.array_equal(out[depth > 0], depth[depth > 0])
    assert np.all(out[:, 10:14] == 3.0)      # the shadow gets the background behind it
    assert np.all(out[5:8, 30:34] == 3.0)
    assert np.array_equal(filled_depth(depth, 0.0), depth)
    far = np.zeros((20, 40), np.float32)
    far[:, :5] = 2.0
    grown = filled_depth(far, 0.1)
    assert np.all(grown[:, 5:9] == 2.0) and np.all(grown[:, 9:] == 0)     # nothing beyond 4 px


def test_hole_filling_densifies_only_empty_depthless_pixels():
    from splat_core.densify import filled_depth, hole_pixel_mask
    cfg = DensifyConfig(hole_fill=0.1)
    depth = np.full((20, 40), 2.0, np.float32)
    depth[5:10, 5:10] = 0                    # a hole the map does not cover
    depth[12:16, 20:25] = 0                  # a hole the map covers already
    silhouette = np.ones((20, 40), np.float32)
    silhouette[:, :15] = 0.1
    mask = hole_pixel_mask(depth, filled_depth(depth, cfg.hole_fill), silhouette, cfg)
    expected = np.zeros_like(mask)
    expected[5:10, 5:10] = True
    assert np.array_equal(mask, expected)
    assert hole_pixel_mask(depth, filled_depth(depth, cfg.hole_fill), None, cfg).sum() == 25 + 20
