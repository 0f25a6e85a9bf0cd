"""Camera conventions: back-projection, quaternions, constant velocity, scaled intrinsics."""

from __future__ import annotations

import numpy as np

from splat_core.camera import (Intrinsics, backproject, pose_matrix, predict_constant_velocity, project,
                               quat_to_rotmat_np, rotmat_to_quat)


def test_backprojected_pixel_reprojects_onto_itself():
    intr = Intrinsics(50.0, 52.0, 31.3, 22.7, 64, 48)
    depth = np.random.default_rng(0).uniform(0.5, 4.0, (48, 64))
    uv = project(backproject(depth, intr), intr)
    u, v = np.meshgrid(np.arange(64), np.arange(48))
    assert np.allclose(uv[..., 0], u) and np.allclose(uv[..., 1], v)


def test_quaternion_round_trip_and_constant_velocity():
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q *= np.sign(q[0])
        assert np.allclose(rotmat_to_quat(quat_to_rotmat_np(q)), q, atol=1e-12)
    step = pose_matrix(quat_to_rotmat_np([0.999, 0.02, -0.03, 0.01]), [0.01, -0.02, 0.005])
    w0 = pose_matrix(quat_to_rotmat_np([0.9, 0.1, 0.3, -0.2]), [0.3, 0.1, -1.0])
    w1 = step @ w0
    assert np.allclose(predict_constant_velocity(w1, w0), step @ w1)
    assert np.allclose(predict_constant_velocity(w1, None), w1)


def test_intrinsics_scaling_keeps_pixel_centres():
    intr = Intrinsics(100.0, 100.0, 63.5, 47.5, 128, 96)       # exact centre of a 128x96 image
    half = intr.scaled(64, 48)
    assert (half.cx, half.cy, half.fx) == (31.5, 23.5, 50.0)
