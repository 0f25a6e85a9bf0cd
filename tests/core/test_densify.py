"""Densification (densify.py): new Gaussians only where the map is empty or behind, on back-projected pixels."""

from __future__ import annotations

import numpy as np
import pytest
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


def test_hole_filled_gaussians_are_marked_guessed_until_a_frame_measures_their_depth():
    from splat_core.config import load_config
    from splat_core.densify import check_guessed, frame_gaussians
    from splat_core.gaussians import GaussianMap
    from splat_core.render import Renderer
    f = small_source(n=1, w=80, h=60)[0]
    depth = f.depth.copy()
    depth[20:30, 30:40] = 0                                  # a hole in the middle of the frame
    config = load_config(overrides={"densify": {"hole_fill": 0.1}})
    new = frame_gaussians(GaussianMap.empty(), Renderer(), f.intrinsics, f.color, depth, np.eye(4), 0, config)
    assert len(new) == int((f.depth > 0).sum()) and int(new.guessed.sum()) == 100
    # Only the hole's Gaussians are guessed: their centres back-project from the hole's pixels.
    u = np.rint(project(new.means.detach().numpy()[new.guessed.numpy()], f.intrinsics)).astype(int)
    assert u[:, 0].min() >= 30 and u[:, 0].max() < 40 and u[:, 1].min() >= 20 and u[:, 1].max() < 30
    # Marks travel with append, prune and the map's arrays.
    m = GaussianMap.empty()
    m.append(new)
    m.prune(torch.arange(len(m)) % 2 == 0)
    assert int(m.guessed.sum()) == 50
    assert torch.equal(GaussianMap.from_numpy(m.to_numpy()).guessed, m.guessed)
    assert "guessed" not in GaussianMap.from_numpy({**m.to_numpy(), "guessed": np.zeros(len(m), bool)}).to_numpy()
    # A frame whose depth agrees confirms them; a surface in front of them, or a frame with the same
    # hole, confirms nothing; a frame that sees through them (a depth behind) removes them.
    before = m.guessed.clone()
    assert check_guessed(m, depth, f.intrinsics, np.eye(4)) == (0, 0)
    nearer = np.where(depth > 0, depth, 0.5 * f.depth).astype(np.float32)
    assert check_guessed(m, nearer, f.intrinsics, np.eye(4)) == (0, 0) and torch.equal(m.guessed, before)
    from splat_core.densify import filled_depth
    agreeing = filled_depth(depth, 0.1)                      # the depth the hole was filled with
    beyond = np.where(depth > 0, depth, 1.5 * agreeing).astype(np.float32)
    seen_through = GaussianMap.from_numpy(m.to_numpy())
    assert check_guessed(seen_through, beyond, f.intrinsics, np.eye(4), carve=False) == (0, 0)
    assert check_guessed(seen_through, beyond, f.intrinsics, np.eye(4)) == (0, int(before.sum()))
    assert len(seen_through) == len(m) - int(before.sum()) and not bool(seen_through.guessed.any())
    assert check_guessed(m, agreeing, f.intrinsics, np.eye(4)) == (int(before.sum()), 0)
    assert not bool(m.guessed.any()) and len(m) == len(seen_through) + int(before.sum())


@pytest.mark.parametrize("tracked", [True, False])
def test_splatam_hands_the_guessed_marks_to_tracking_only_when_they_are_left_out(tracked):
    import dataclasses
    from splat_core.config import load_config
    from splat_core.slam import SplaTAM
    src = small_source(n=3, w=80, h=60)
    config = load_config("cpu", overrides={"resolution": [80, 60], "densify": {"hole_fill": 0.1,
                                                                                "hole_fill_tracked": tracked},
                                            "mapping": {"first_frame_iterations": 5, "iterations": 2}})
    slam = SplaTAM(config, src[0].intrinsics, total_frames=3)
    seen, track = [], slam.tracker.track

    def spy(gaussians, color, depth, w2c, reuse=False, **kw):
        seen.append(kw.get("exclude"))
        return track(gaussians, color, depth, w2c, reuse, **kw)
    slam.tracker.track = spy
    for i in range(3):
        frame = src[i]
        depth = frame.depth.copy()
        depth[20:30, 30:40] = 0                  # the same hole in every frame: its Gaussians stay guessed
        slam.process(dataclasses.replace(frame, depth=depth))
    assert int(slam.map.guessed.sum()) > 0 and len(seen) == 2
    if tracked:
        assert all(e is None for e in seen)
    else:
        assert all(e is not None and e.dtype == torch.bool and int(e.sum()) > 0 for e in seen)
