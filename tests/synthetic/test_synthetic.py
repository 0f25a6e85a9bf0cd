"""The synthetic scene: exact geometry, consistent poses, determinism, sensor options."""


import numpy as np
import pytest

from splat_core.camera import Intrinsics, backproject, invert_pose, project
from splat_core.frame import Frame
from splat_core.io.source import FrameSource
from splat_core.synthetic import (
    ROOM_MAX, SyntheticScene, SyntheticSource, camera_path, default_intrinsics, look_at_c2w,
    render_view,
)

SMALL = dict(n_frames=12, width=64, height=48)


def test_frame_shapes_dtypes_and_source_contract():
    src = SyntheticSource(**SMALL)
    assert isinstance(src, FrameSource)
    assert src.format_name == "synthetic" and len(src) == 12 and src.has_reference_poses
    f = src[3]
    assert isinstance(f, Frame) and f.index == 3
    assert f.color.shape == (48, 64, 3) and f.color.dtype == np.float32
    assert f.depth.shape == (48, 64) and f.depth.dtype == np.float32
    assert 0.0 <= f.color.min() and f.color.max() <= 1.0
    assert np.all(f.depth > 0)  # closed room, no holes by default
    assert f.intrinsics == src.intrinsics
    np.testing.assert_array_equal(f.c2w_ref, src.reference_c2w()[3])
    assert src.timestamps.shape == (12,) and f.timestamp == pytest.approx(3 / 30)
    assert src.reference_c2w().shape == (12, 4, 4)
    assert len(list(src)) == 12
    with pytest.raises(IndexError):
        src[12]


def test_poses_are_rigid_and_motion_is_handheld_like():
    c2w = camera_path(120, seed=0)
    R = c2w[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    step = np.linalg.norm(np.diff(c2w[:, :3, 3], axis=0), axis=1)
    assert 0.005 < step.mean() < 0.03
    rel = np.stack([invert_pose(c2w[i]) @ c2w[i + 1] for i in range(len(c2w) - 1)])
    angle = np.degrees(np.arccos(np.clip((np.trace(rel[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert 0.2 < angle.mean() < 1.5 and angle.max() < 2.0
    # Rotation about more than one axis: the viewing direction changes in elevation too, and rolls.
    forward = c2w[:, :3, 2]
    assert np.ptp(forward[:, 1]) > 0.02                     # pitch varies (world y is down)
    assert np.ptp(c2w[:, 1, 0]) > 0.02                      # camera x axis tilts: roll varies
    # The path does not depend on the sequence length.
    np.testing.assert_array_equal(camera_path(10, seed=0), c2w[:10])


def test_depth_is_camera_z_to_a_known_plane():
    # Camera 1 m above the floor (floor plane y = +1.5, world y down), looking straight down.
    intr = default_intrinsics(40, 30, fov_deg=50.0)
    eye = np.array([-2.0, 0.5, -2.0])   # away from the objects
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], dtype=float)  # camera z -> world +y (down)
    c2w[:3, 3] = eye
    _, depth = render_view(c2w, intr)
    np.testing.assert_allclose(depth, 1.0, atol=1e-6)   # camera z is constant over a fronto-parallel plane

    # Tilted view of the wall x = +3: depth = camera z of the ray / plane intersection.
    c2w = look_at_c2w([2.0, 0.0, -2.5], [3.0, -0.3, -2.0])
    color, depth = render_view(c2w, intr)
    pts_cam = backproject(depth, intr)
    pts_world = pts_cam.reshape(-1, 3) @ c2w[:3, :3].T + c2w[:3, 3]
    np.testing.assert_allclose(pts_world[:, 0], ROOM_MAX[0], atol=1e-5)
    # And analytically for one pixel: ray r = R K^-1 (u, v, 1), t = (3 - ex) / r_x, depth = t.
    u, v = 7, 22
    r = c2w[:3, :3] @ np.array([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, 1.0])
    assert depth[v, u] == pytest.approx((3.0 - 2.0) / r[0], rel=1e-6)


def _reprojection_errors(src: SyntheticSource, i: int, j: int, c2w_j=None) -> np.ndarray:
    intr = src.intrinsics
    fi, fj = src[i], src[j]
    if c2w_j is not None:
        fj.c2w_ref = c2w_j
    pts_i = backproject(fi.depth, intr).reshape(-1, 3)
    world = pts_i @ fi.c2w_ref[:3, :3].T + fi.c2w_ref[:3, 3]
    w2c_j = invert_pose(fj.c2w_ref)
    pts_j = world @ w2c_j[:3, :3].T + w2c_j[:3, 3]
    uv = project(pts_j, intr)
    u, v = uv[:, 0], uv[:, 1]
    inside = (u >= 0) & (u <= intr.width - 1.001) & (v >= 0) & (v <= intr.height - 1.001) & (pts_j[:, 2] > 0)
    u, v, z = u[inside], v[inside], pts_j[inside, 2]
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    a, b = u - u0, v - v0
    d = fj.depth.astype(np.float64)
    corners = np.stack([d[v0, u0], d[v0, u0 + 1], d[v0 + 1, u0], d[v0 + 1, u0 + 1]])
    smooth = np.ptp(corners, axis=0) < 0.05      # skip depth discontinuities (and occlusions)
    interp = ((1 - a) * (1 - b) * corners[0] + a * (1 - b) * corners[1]
              + (1 - a) * b * corners[2] + a * b * corners[3])
    return np.abs(interp - z)[smooth]


def test_exact_poses_reproject_depth_between_frames():
    src = SyntheticSource(n_frames=31, width=160, height=120, seed=3)
    for i, j in [(0, 5), (10, 30)]:
        err = _reprojection_errors(src, i, j)
        assert err.size > 0.5 * 160 * 120
        assert np.median(err) < 1e-3
    # The check has teeth: a 2 cm error in the pose of frame j breaks it.
    wrong = src.c2w[5].copy()
    wrong[:3, 3] += np.array([0.02, 0.0, 0.0])
    assert np.median(_reprojection_errors(src, 0, 5, c2w_j=wrong)) > 3e-3


def test_colour_is_view_independent():
    src = SyntheticSource(n_frames=20, width=160, height=120, seed=1)
    fi, fj = src[0], src[19]
    intr = src.intrinsics
    pts = backproject(fi.depth, intr).reshape(-1, 3) @ fi.c2w_ref[:3, :3].T + fi.c2w_ref[:3, 3]
    w2c = invert_pose(fj.c2w_ref)
    pj = pts @ w2c[:3, :3].T + w2c[:3, 3]
    uv = np.rint(project(pj, intr)).astype(int)
    ok = (uv[:, 0] >= 0) & (uv[:, 0] < intr.width) & (uv[:, 1] >= 0) & (uv[:, 1] < intr.height)
    ok &= np.abs(fj.depth[np.clip(uv[:, 1], 0, 119), np.clip(uv[:, 0], 0, 159)] - pj[:, 2]) < 0.01
    diff = np.abs(fi.color.reshape(-1, 3)[ok] - fj.color[uv[ok, 1], uv[ok, 0]])
    assert ok.sum() > 1000 and np.median(diff) < 0.05


def test_textured_not_flat():
    f = SyntheticSource(**SMALL)[0]
    assert f.color.reshape(-1, 3).std(axis=0).min() > 0.03
    # Local texture: neighbouring pixels differ noticeably in many places.
    grad = np.abs(np.diff(f.color, axis=1)).sum(-1)
    assert np.mean(grad > 0.02) > 0.1


def test_deterministic_by_seed():
    a, b, c = (SyntheticSource(**SMALL, seed=s, noise=0.002, holes=0.05)[5] for s in (0, 0, 1))
    np.testing.assert_array_equal(a.color, b.color)
    np.testing.assert_array_equal(a.depth, b.depth)
    np.testing.assert_array_equal(a.c2w_ref, b.c2w_ref)
    assert not np.array_equal(a.color, c.color)
    assert not np.allclose(a.c2w_ref, c.c2w_ref)
    # Random access gives the same frame as sequential access.
    src = SyntheticSource(**SMALL, seed=0, noise=0.002, holes=0.05)
    _ = [src[i] for i in range(5)]
    np.testing.assert_array_equal(src[5].depth, a.depth)


def test_depth_noise_scales_with_depth_squared():
    clean = SyntheticSource(n_frames=2, width=160, height=120)[1]
    noisy = SyntheticSource(n_frames=2, width=160, height=120, noise=0.003)[1]
    np.testing.assert_array_equal(clean.color, noisy.color)
    z = clean.depth.astype(np.float64)
    r = (noisy.depth - z) / z ** 2
    assert abs(r.std() - 0.003) < 0.0003 and abs(r.mean()) < 0.0003
    assert np.all(noisy.depth > 0)


def test_holes_are_blobs_of_the_requested_fraction_and_far_cutoff():
    src = SyntheticSource(n_frames=2, width=160, height=120, holes=0.1)
    d = src[1].depth
    invalid = d == 0
    assert abs(invalid.mean() - 0.1) < 0.01
    # Blobs, not salt-and-pepper: most invalid pixels have an invalid right neighbour.
    assert (invalid[:, :-1] & invalid[:, 1:]).sum() > 0.8 * invalid[:, :-1].sum()
    # Holes only remove depth; the rest is unchanged.
    clean = SyntheticSource(n_frames=2, width=160, height=120)[1].depth
    np.testing.assert_array_equal(d[~invalid], clean[~invalid])

    cut = SyntheticSource(n_frames=2, width=160, height=120, max_depth=3.0)[1].depth
    assert cut.max() <= 3.0
    np.testing.assert_array_equal(cut == 0, clean > 3.0)
    assert (clean > 3.0).any()


def test_explicit_intrinsics_and_novel_views():
    intr = Intrinsics(50.0, 55.0, 20.0, 14.0, 41, 29)
    src = SyntheticSource(n_frames=3, intrinsics=intr)
    assert src[0].color.shape == (29, 41, 3)
    color, depth = src.render_view(src.c2w[0])
    np.testing.assert_array_equal(color, src[0].color)
    np.testing.assert_array_equal(depth, src[0].depth)
    c2, d2 = src.render_view(src.c2w[0], default_intrinsics(20, 10))
    assert c2.shape == (10, 20, 3) and d2.shape == (10, 20)
    with pytest.raises(ValueError):
        SyntheticScene().render(look_at_c2w([5.0, 0, 0], [0, 0, 0]), intr)


def test_frames_after_the_first_render():
    # Was a speed check (< 1 s a frame); speed belongs to benchmarks/, tests assert no durations.
    src = SyntheticSource(n_frames=5, width=320, height=240)
    for i in range(5):
        f = src[i]
        assert f.color.shape == (240, 320, 3) and f.depth.shape == (240, 320) and (f.depth > 0).any()


@pytest.mark.parametrize("source", ["orbit", "corridor", "lap", "small"])
def test_the_numba_ray_caster_draws_what_the_numpy_one_did(source):
    """raycast.py reproduces the numpy caster it replaced (helpers/numpy_scene.py) operation for
    operation: the same float32 frames, up to a rare last-bit flip where numpy's own SIMD tanh
    differs from libm's (none on the machines measured: docs/benchmarks.md, "Live rate")."""
    from helpers.numpy_scene import render_numpy

    from splat_core.synthetic import CorridorSource, LoopSource
    src = {"orbit": lambda: SyntheticSource(), "corridor": lambda: CorridorSource(n_frames=400),
           "lap": lambda: LoopSource(), "small": lambda: SyntheticSource(seed=3, width=80, height=60)}[source]()
    for i in np.linspace(0, len(src) - 1, 4).astype(int):
        color, depth = src.scene.render(src.c2w[i], src.intrinsics)
        color0, depth0 = render_numpy(src.scene, src.c2w[i], src.intrinsics)
        assert color.dtype == np.float32 and depth.dtype == np.float32
        np.testing.assert_allclose(color, color0, rtol=0, atol=1e-6)
        np.testing.assert_allclose(depth, depth0, rtol=1e-6, atol=0)
        assert (color != color0).mean() < 1e-4 and (depth != depth0).mean() < 1e-4
