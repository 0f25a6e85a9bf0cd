"""Camera paths for videos: through the given poses, smooth, constant-ish speed."""

from __future__ import annotations

import numpy as np
import pytest

from splat_core.camera import pose_matrix, rotmat_to_quat
from splat_core.camera_path import CameraPath, turn_angle
from splat_core.synthetic import look_at_c2w


def keyframes() -> np.ndarray:
    """Five poses on an arc around a point, unevenly spaced, with a turn at each."""
    target = np.array([0.0, 0.0, 3.0])
    eyes = [(-1.0, -0.2, 0.0), (-0.4, -0.3, 0.3), (0.0, -0.2, 0.4), (0.9, 0.0, 0.2), (1.2, 0.1, 1.0)]
    return np.stack([look_at_c2w(np.array(e), target) for e in eyes])


def rotation_steps(c2ws: np.ndarray) -> np.ndarray:
    q = [rotmat_to_quat(T[:3, :3]) for T in c2ws]
    return np.array([turn_angle(a, b) for a, b in zip(q[:-1], q[1:])])


def test_path_passes_through_the_keyframes():
    kf = keyframes()
    path = CameraPath(kf)
    assert path.knots[0] == 0.0 and path.knots[-1] == 1.0 and np.all(np.diff(path.knots) > 0)
    for s, c2w in zip(path.knots, kf):
        assert np.allclose(path.at(s), c2w, atol=1e-9)
    assert np.allclose(path.sample(7)[0], kf[0]) and np.allclose(path.sample(7)[-1], kf[-1])


def test_path_is_smooth_no_jumps():
    path = CameraPath(keyframes())
    c2ws = path.sample(400)
    for T in c2ws:   # proper rotations all along
        assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9) and np.linalg.det(T[:3, :3]) > 0
    steps = np.linalg.norm(np.diff(c2ws[:, :3, 3], axis=0), axis=1)
    # constant-ish speed: no step far above the typical one, and speed changes gradually
    assert steps.max() < 2.0 * np.median(steps)
    assert np.abs(np.diff(steps)).max() < 0.05 * np.median(steps)
    turns = rotation_steps(c2ws)
    assert turns.max() < 3.0 * np.median(turns) and turns.max() < np.deg2rad(1.0)
    assert np.abs(np.diff(turns)).max() < 0.1 * turns.max()


def test_linear_motion_stays_on_the_line():
    c2ws = np.stack([pose_matrix(np.eye(3), [x, 0.0, 0.0]) for x in (0.0, 0.5, 1.0, 1.5)])
    samples = CameraPath(c2ws).sample(31)
    assert np.allclose(samples[:, 1:3, 3], 0.0) and np.allclose(samples[:, :3, :3], np.eye(3))
    assert np.allclose(samples[:, 0, 3], np.linspace(0.0, 1.5, 31), atol=1e-9)   # even steps


def test_turning_past_180_degrees_does_not_spin_the_camera():
    """rotmat_to_quat returns w >= 0, so a yaw through 180 degrees flips the quaternion's sign
    (q and -q are one rotation); the path must still turn the short way, 25 degrees per pose."""
    def yaw(deg):
        a = np.deg2rad(deg)
        return pose_matrix(np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]), [0, 0, 0])
    kf = np.stack([yaw(d) for d in (150, 175, 200, 225)])
    assert np.dot(rotmat_to_quat(kf[1][:3, :3]), rotmat_to_quat(kf[2][:3, :3])) < 0
    turns = rotation_steps(CameraPath(kf).sample(76))
    assert np.isclose(turns.sum(), np.deg2rad(75.0), rtol=1e-3) and turns.max() < np.deg2rad(1.5)


def test_one_pose_and_no_pose():
    c2w = look_at_c2w(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    assert np.allclose(CameraPath(c2w[None]).sample(3), c2w)
    with pytest.raises(ValueError):
        CameraPath(np.zeros((0, 4, 4)))
