"""Camera conventions: back-projection, quaternions, constant velocity, scaled intrinsics."""

from __future__ import annotations

import numpy as np

from splat_core.camera import (Intrinsics, backproject, invert_pose, invert_poses, pose_matrix, predict_constant_velocity,
                               project, quat_to_rotmat_np, rotmat_to_quat, scale_motion, se3_exp, se3_log)


def test_backprojected_pixel_reprojects_onto_itself():
    intr = Intrinsics(50.0, 52.0, 31.3, 22.7, 64, 48)
    depth = np.random.default_rng(0).uniform(0.5, 4.0, (48, 64))
    uv = project(backproject(depth, intr), intr)
    u, v = np.meshgrid(np.arange(64), np.arange(48))
    assert np.allclose(uv[..., 0], u) and np.allclose(uv[..., 1], v)


def test_invert_poses_gives_invert_pose_numbers_exactly():
    """The batched inverse (a viewer's whole trajectory after every frame) is bit for bit the
    per-pose one, so trajectory.txt does not change; each dtype, and 1 to 200 poses at a time."""
    rng = np.random.default_rng(7)
    for n in (1, 2, 3, 17, 200):
        q = rng.normal(size=(n, 4))
        poses = np.stack([pose_matrix(quat_to_rotmat_np(x / np.linalg.norm(x)), rng.normal(size=3) * 5) for x in q])
        poses[0] = np.eye(4)                           # the first frame's pose: zeros keep their sign
        for dtype in (np.float64, np.float32):
            batch = [p.astype(dtype) for p in poses]
            got = invert_poses(batch)
            assert got.dtype == np.float64 and got.shape == (n, 4, 4)
            assert got.tobytes() == np.stack([invert_pose(p) for p in batch]).tobytes()   # -0.0 too
    assert np.allclose(invert_poses(poses) @ poses, np.eye(4), atol=1e-12)
    lost = poses[:2].copy()
    lost[1] = np.nan                                   # a NaN pose stays NaN, as invert_pose's
    assert np.isnan(invert_poses(lost)[1, :3]).all() and np.isfinite(invert_poses(lost)[0]).all()


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


def test_gap_scaled_prediction_is_exact_on_a_constant_twist_sampled_at_irregular_times():
    # A camera on a constant screw motion (c2w(s) = c2w0 exp(s xi)), sampled with the uneven gaps a
    # real-time playback leaves (3 capture frames, then 11, ...): the last motion scaled by the
    # ratio of the gaps predicts every next pose exactly; the unscaled prediction does not.
    w, u = np.array([0.004, -0.011, 0.007]), np.array([0.003, 0.001, -0.004])     # per capture frame
    c2w0 = pose_matrix(quat_to_rotmat_np([0.9, 0.1, 0.3, -0.2]), [0.3, 0.1, -1.0])
    times = [0, 1, 4, 15, 16, 29, 31, 32, 52]
    w2cs = [invert_pose(c2w0 @ se3_exp(s * w, s * u)) for s in times]
    worst_unscaled = 0.0
    for k in range(2, len(times)):
        ratio = (times[k] - times[k - 1]) / (times[k - 1] - times[k - 2])
        assert np.allclose(predict_constant_velocity(w2cs[k - 1], w2cs[k - 2], ratio), w2cs[k], atol=1e-12)
        worst_unscaled = max(worst_unscaled, np.abs(predict_constant_velocity(w2cs[k - 1], w2cs[k - 2])
                                                     - w2cs[k]).max())
    assert worst_unscaled > 0.05


def test_se3_log_exp_round_trip_and_scaling_from_no_turn_to_half_a_turn():
    rng = np.random.default_rng(3)
    for theta in (0.0, 1e-9, 1e-4, 0.3, 2.0, np.pi - 1e-6, np.pi):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        T = se3_exp(theta * axis, rng.normal(size=3))
        assert np.allclose(se3_exp(*se3_log(T)), T, atol=1e-12)
        half = scale_motion(T, 0.5)
        assert np.allclose(half @ half, T, atol=1e-12)
    T = se3_exp(np.array([0.1, 0.2, -0.3]), np.array([1.0, 2.0, 3.0]))
    assert scale_motion(T, 1.0) is T          # ratio 1: the unscaled motion, bit for bit


def test_intrinsics_scaling_keeps_pixel_centres():
    intr = Intrinsics(100.0, 100.0, 63.5, 47.5, 128, 96)       # exact centre of a 128x96 image
    half = intr.scaled(64, 48)
    assert (half.cx, half.cy, half.fx) == (31.5, 23.5, 50.0)
