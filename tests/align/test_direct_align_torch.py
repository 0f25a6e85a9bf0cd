"""The direct alignment in torch (align/torch_backend.py) against the Numba version (align/numba_backend.py),
on CPU tensors in float64: the pyramid's resizes against OpenCV, the normal equations and the step
on the same level, the whole alignment on the same map; and convergence to an exact known pose."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from splat_core.align import numba_backend as nb
from splat_core.align import resolve_backend
from splat_core.align import torch_backend as tt
from splat_core.camera import Intrinsics
from splat_core.config import DensifyConfig, load_config
from splat_core.densify import gaussians_from_pixels
from splat_core.frame import resize_to
from splat_core.synthetic import SyntheticSource
from splat_core.tracking import Tracker
from splat_core.render import Renderer


def _t(a):
    return torch.as_tensor(np.ascontiguousarray(a))


# ----------------------------------------------------------------------------- OpenCV's operations

@pytest.mark.parametrize("src,dst", [((240, 320), (120, 160)), ((240, 320), (60, 80)), ((128, 170), (64, 85)),
                                     ((128, 170), (32, 42)), ((97, 131), (49, 66)), ((60, 80), (120, 160))])
def test_resizes_match_opencv(src, dst):
    rng = np.random.default_rng(0)
    image = rng.uniform(0, 5, src)
    intr = Intrinsics(100.0, 100.0, src[1] / 2, src[0] / 2, src[1], src[0]).scaled(dst[1], dst[0])
    assert np.array_equal(tt.resize_nearest(_t(image), *dst).numpy(), resize_to(image, intr, True))
    mask = image > 2.5
    assert np.array_equal(tt.resize_nearest(_t(mask), *dst).numpy(),
                          resize_to(mask.astype(np.uint8), intr, True).astype(bool))
    assert np.allclose(tt.resize_smooth(_t(image), *dst).numpy(), resize_to(image, intr, False), rtol=0, atol=1e-12)


def test_sobel_and_erosion_match_opencv():
    rng = np.random.default_rng(1)
    image = rng.uniform(0, 1, (37, 53))
    gx, gy = tt.sobel(_t(image))
    assert np.allclose(gx.numpy(), cv2.Sobel(image, cv2.CV_64F, 1, 0, ksize=3), atol=1e-12)
    assert np.allclose(gy.numpy(), cv2.Sobel(image, cv2.CV_64F, 0, 1, ksize=3), atol=1e-12)
    mask = rng.uniform(size=(37, 53)) > 0.2
    mask[0, :] = True
    expected = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert np.array_equal(tt.erode3(_t(mask)).numpy(), expected)


# ----------------------------------------------------------------------------- one level, one step

def _frames(w=160, h=120):
    src = SyntheticSource(n_frames=3, width=w, height=h, seed=0)
    return src, src[0], src[2]


def _levels(f0, f2, stride=1):
    """The same level built by both versions from frame 0 (the 'rendering') and frame 2 (live)."""
    d0, d2 = f0.depth.astype(np.float64), f2.depth.astype(np.float64)
    g0, g2 = nb._grey(f0.color.astype(np.float64)), nb._grey(f2.color.astype(np.float64))
    level = nb._Level(f0.intrinsics, d0, g0, d0 > 0, d2, g2, stride)
    level_t = tt.LevelT(f0.intrinsics, _t(d0), _t(g0), _t(d0 > 0), _t(d2), _t(g2), stride)
    return level, level_t


def test_level_arrays_match_the_numba_version():
    _, f0, f2 = _frames()
    level, level_t = _levels(f0, f2, stride=3)
    for name in ("model_points", "model_normals", "model_grad"):
        assert np.allclose(getattr(level_t, name).numpy(), getattr(level, name), rtol=0, atol=1e-12), name
    assert np.array_equal(level_t.model_ok.numpy(), level.model_ok)
    assert np.array_equal(level_t.color_ok.numpy(), level.color_ok)
    # torch keeps the whole stride grid with a validity mask; the Numba version the valid points
    valid = level_t.live_valid.numpy()
    assert np.array_equal(level_t.live_points.numpy()[valid], level.live_points)
    assert np.array_equal(level_t.live_grey.numpy()[valid], level.live_grey)


@pytest.mark.parametrize("depth_noise", [False, True])
def test_normal_equations_and_step_match_the_numba_version(depth_noise):
    _, f0, f2 = _frames()
    level, _ = _levels(f0, f2)
    level_t = tt.LevelT.from_numpy(level)
    X = nb._se3_exp(np.array([0.01, -0.006, 0.004, 0.006, -0.004, 0.008]))
    i = level.intr
    r_d, J_d, ok_d, r_c, J_c, ok_c = nb._linearise(level.live_points, level.live_grey, X, i.fx, i.fy, i.cx, i.cy,
                                                   level.model_points, level.model_normals, level.model_ok,
                                                   level.model_grey, level.model_grad, level.color_ok, 0.1)
    s = nb._noise(1.0) / nb._noise(level.live_points[:, 2]) if depth_noise else np.ones(len(r_d))
    H, g = np.zeros((6, 6)), np.zeros(6)
    nb._add_huber_system(r_d, J_d, ok_d, s, 1e-4, 1.0, H, g)
    nb._add_huber_system(r_c, J_c, ok_c, np.ones(len(r_c)), 1e-3, 0.7, H, g)
    H_t, g_t, count, rmse = tt.normal_equations(level_t, _t(X), 0.7, 0.1, depth_noise)
    assert int(count) == ok_d.sum() > 1000 and ok_c.sum() > 1000
    assert np.allclose(H_t.numpy(), H, rtol=1e-10, atol=0)
    assert np.allclose(g_t.numpy(), g, rtol=1e-10, atol=1e-12 * np.abs(g).max())
    dX, n, err = nb._gauss_newton_step(level, X, 0.7, 0.1, depth_noise)
    dX_t, n_t, err_t = tt.gauss_newton_step(level_t, _t(X), 0.7, 0.1, depth_noise)
    assert int(n_t) == n and np.isclose(float(err_t), err, rtol=1e-12)
    assert np.allclose(dX_t.numpy(), dX, rtol=0, atol=1e-12)
    assert np.abs(dX - np.eye(4)).max() > 1e-3          # a real step, not the identity


def test_too_few_residuals_give_the_identity_step():
    _, f0, f2 = _frames(32, 24)
    level, _ = _levels(f0, f2)
    level_t = tt.LevelT.from_numpy(level)
    far = nb._se3_exp(np.array([0.0, 0.0, -50.0, 0.0, 0.0, 0.0]))   # everything behind the camera
    dX_t, n_t, err_t = tt.gauss_newton_step(level_t, _t(far), 1.0, 0.1)
    assert int(n_t) < 50 and torch.equal(dX_t, torch.eye(4, dtype=torch.float64)) and float(err_t) == np.inf


# ----------------------------------------------------------------------------- the whole alignment

def _map(frame):
    return gaussians_from_pixels(frame.color, frame.depth, frame.depth > 0, frame.intrinsics, np.eye(4), 0,
                                 DensifyConfig(), True).tensors(detach=True)


@pytest.mark.parametrize("options", [dict(passes=2, live_stride=2, depth_noise=True),
                                     dict(passes=1, live_stride=1, color_weight=0.0)])
def test_alignment_matches_the_numba_version_on_the_same_map(options):
    src, f0, f2 = _frames()
    g = _map(f0)
    start = np.eye(4)
    ref = nb.align_to_map(g, f2.color, f2.depth, f2.intrinsics, start, iterations=10, **options)
    for sync in (True, False):        # sync=False: the CUDA control flow (device flags, no early stop)
        out = tt.align_to_map_torch(g, f2.color, f2.depth, f2.intrinsics, start, iterations=10, sync=sync, **options)
        assert out.correspondences == ref.correspondences > 1000
        assert np.allclose(out.w2c, ref.w2c, rtol=0, atol=1e-9), np.abs(out.w2c - ref.w2c).max()
        assert np.isclose(out.rmse_depth, ref.rmse_depth, rtol=1e-8)
        assert torch.equal(out.first_render.depth, ref.first_render.depth)
    assert np.abs(ref.w2c - start).max() > 1e-3


def test_alignment_keeps_the_start_when_the_map_is_out_of_view():
    _, f0, _ = _frames(64, 48)
    away = np.diag([-1.0, 1.0, -1.0, 1.0])                 # looking backwards
    for sync in (True, False):
        out = tt.align_to_map_torch(_map(f0), f0.color, f0.depth, f0.intrinsics, away, sync=sync)
        assert np.array_equal(out.w2c, away) and out.correspondences < 50


# ----------------------------------------------------------------------------- exact convergence

def _raycast(intr: Intrinsics, R: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Depth seen by a camera at (R, c) (camera -> scene) of a wall at z = 4 with two tilted panels
    in front of it, separated from it by depth jumps (so every surface a residual uses is a plane)."""
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float64), np.arange(intr.height, dtype=np.float64))
    d = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], -1)   # camera rays, z = 1
    dw = d @ R.T
    depth = np.full(u.shape, np.inf)
    planes = [(np.array([0.0, 0.0, 1.0]), 4.0, None),
              (np.array([0.5, 0.0, 1.0]) / np.linalg.norm([0.5, 0.0, 1.0]), 1.6, (-2.0, -0.25)),
              (np.array([0.0, 0.6, 1.0]) / np.linalg.norm([0.0, 0.6, 1.0]), 2.2, (0.25, 2.0))]
    for n, k, xs in planes:
        t = (k - n @ c) / (dw @ n)
        hit = c + t[..., None] * dw
        inside = t > 0
        if xs is not None:
            inside &= (hit[..., 0] > xs[0]) & (hit[..., 0] < xs[1]) & (np.abs(hit[..., 1]) < 1.2)
        depth = np.where(inside & (t < depth), t, depth)
    return np.where(np.isfinite(depth), depth, 0.0)


def test_gauss_newton_converges_to_an_exact_known_pose():
    intr = Intrinsics(110.0, 110.0, 79.5, 59.5, 160, 120)
    X_true = nb._se3_exp(np.array([0.03, -0.02, 0.025, 0.012, -0.018, 0.01]))   # live camera -> model camera
    model_depth = _raycast(intr, np.eye(3), np.zeros(3))
    live_depth = _raycast(intr, X_true[:3, :3], X_true[:3, 3])
    zeros = np.zeros_like(model_depth)
    level_t = tt.LevelT(intr, _t(model_depth), _t(zeros), _t(model_depth > 0), _t(live_depth), _t(zeros))
    level = nb._Level(intr, model_depth, zeros, model_depth > 0, live_depth, zeros)
    X_t, X = torch.eye(4, dtype=torch.float64), np.eye(4)
    for _ in range(15):
        X_t = tt.gauss_newton_step(level_t, X_t, 0.0, 0.1)[0] @ X_t
        X = nb._gauss_newton_step(level, X, 0.0, 0.1)[0] @ X
    assert np.abs(X_true - np.eye(4)).max() > 0.02
    assert np.abs(X_t.numpy() - X_true).max() < 1e-9
    assert np.abs(X - X_true).max() < 1e-9


# ----------------------------------------------------------------------------- the tracker's choice

def test_tracker_uses_the_configured_backend():
    assert resolve_backend("auto", "cpu") == "numba" and resolve_backend("auto", "cuda") == "torch"
    assert resolve_backend("torch", "cpu") == "torch"
    with pytest.raises(ValueError):
        resolve_backend("opencv", "cpu")
    _, f0, f2 = _frames(80, 60)
    results = {}
    for backend in ("numba", "torch"):
        cfg = load_config("cpu", overrides={"tracking": {"align": {"backend": backend}}})
        tracker = Tracker(cfg.tracking, f0.intrinsics, Renderer())
        results[backend] = tracker.align(_map(f0), f2.color, f2.depth, np.eye(4))
    assert np.allclose(results["torch"].w2c, results["numba"].w2c, rtol=0, atol=1e-9)
    assert np.abs(results["torch"].w2c - np.eye(4)).max() > 1e-3       # it moved: a real alignment


def test_the_front_door_runs_the_chosen_backend_unchanged():
    # align.align_to_map only picks: its result is each backend's own, bit for bit.
    from splat_core.align import align_to_map
    _, f0, f2 = _frames(80, 60)
    g = _map(f0)
    options = dict(iterations=5, passes=2, live_stride=2)
    numba = nb.align_to_map(g, f2.color, f2.depth, f2.intrinsics, np.eye(4), **options)
    torch_ = tt.align_to_map_torch(g, f2.color, f2.depth, f2.intrinsics, np.eye(4), **options)
    for backend, expected in (("auto", numba), ("numba", numba), ("torch", torch_)):
        out = align_to_map(g, f2.color, f2.depth, f2.intrinsics, np.eye(4), backend=backend, **options)
        assert np.array_equal(out.w2c, expected.w2c) and out.correspondences == expected.correspondences, backend
        assert torch.equal(out.first_render.depth, expected.first_render.depth)
