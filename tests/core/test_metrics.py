"""Evaluation metrics against hand-computed values."""

import numpy as np
import pytest
import torch

from splat_core.camera import invert_pose, pose_matrix, quat_to_rotmat_np
from splat_core.metrics import (
    RunningAte, align_rigid, ate_errors, ate_mean_legacy, ate_rmse, depth_l1, psnr, relative_pose_errors,
    ssim_metric,
)


def _rot(axis, deg):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    h = np.radians(deg) / 2
    return quat_to_rotmat_np(np.r_[np.cos(h), np.sin(h) * axis])


def _poses(centres, rotations=None):
    n = len(centres)
    rotations = [np.eye(3)] * n if rotations is None else rotations
    return np.stack([pose_matrix(R, c) for R, c in zip(rotations, centres)])


def test_align_rigid_recovers_a_known_transform():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(20, 3))
    R_true, t_true = _rot([1, 2, -0.5], 73.0), np.array([0.4, -2.0, 1.5])
    R, t = align_rigid(src, src @ R_true.T + t_true)
    np.testing.assert_allclose(R, R_true, atol=1e-12)
    np.testing.assert_allclose(t, t_true, atol=1e-12)
    # Torch input works too.
    R2, _ = align_rigid(torch.tensor(src), torch.tensor(src @ R_true.T + t_true))
    np.testing.assert_allclose(R2, R_true, atol=1e-12)


def test_align_rigid_never_returns_a_reflection():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(10, 3))
    mirrored = src * np.array([1.0, 1.0, -1.0])
    R, _ = align_rigid(src, mirrored)
    assert np.linalg.det(R) == pytest.approx(1.0)
    # Planar point sets (rank-deficient covariance) still give a proper rotation.
    planar = src.copy()
    planar[:, 2] = 0
    R, t = align_rigid(planar, planar @ _rot([0, 0, 1], 30).T)
    np.testing.assert_allclose(R, _rot([0, 0, 1], 30), atol=1e-12)


def test_ate_zero_for_a_rigidly_moved_trajectory():
    rng = np.random.default_rng(2)
    ref = _poses(rng.normal(size=(15, 3)), [_rot(rng.normal(size=3), rng.uniform(0, 90)) for _ in range(15)])
    T = pose_matrix(_rot([0.3, -1, 2], 40), [1.0, 2.0, -3.0])
    est = T @ ref
    assert ate_rmse(est, ref) == pytest.approx(0.0, abs=1e-12)
    # The legacy number (w2c translation columns t = -R^T c) is only invariant to a rotation of
    # the world about its origin; a translated world frame leaks each frame's rotation into it.
    # SplaTAM gets away with this because both trajectories start at the identity.
    def legacy(est_c2w):
        return ate_mean_legacy(np.stack([invert_pose(p) for p in est_c2w]),
                               np.stack([invert_pose(p) for p in ref]))
    assert legacy(ref) == pytest.approx(0.0, abs=1e-12)
    assert legacy(pose_matrix(_rot([0.3, -1, 2], 40), np.zeros(3)) @ ref) == pytest.approx(0.0, abs=1e-12)
    assert legacy(T @ ref) > 0.1


# A hand-solvable case: centres on a unit square's corners plus its centre; the estimate is lifted
# out of the plane by z = d*x*y (+d, -d, +d, -d at the corners, 0 at the centre). The offsets have
# zero mean and are orthogonal to every tilt and in-plane rotation of the square (sum xy*x =
# sum xy*y = 0), so the best rigid alignment is the identity and the per-frame errors stay
# d, d, d, d, 0: RMSE = d * sqrt(4/5), mean = 4d/5.
D = 0.05
SQUARE = np.array([[1, 1, 0], [1, -1, 0], [-1, -1, 0], [-1, 1, 0], [0, 0, 0]], dtype=float)
LIFTED = SQUARE + np.c_[np.zeros((5, 2)), D * SQUARE[:, 0] * SQUARE[:, 1]]


def test_ate_rmse_of_a_known_residual():
    ref, est = _poses(SQUARE), _poses(LIFTED)
    np.testing.assert_allclose(ate_errors(est, ref), [D, D, D, D, 0], atol=1e-12)
    assert ate_rmse(est, ref) == pytest.approx(D * np.sqrt(4 / 5), abs=1e-12)
    # The same after moving the whole estimate rigidly, and symmetric in its arguments.
    T = pose_matrix(_rot([1, 1, 0], 25), [3.0, 0.0, -1.0])
    assert ate_rmse(T @ est, ref) == pytest.approx(D * np.sqrt(4 / 5), abs=1e-12)
    assert ate_rmse(ref, T @ est) == pytest.approx(D * np.sqrt(4 / 5), abs=1e-12)


def test_legacy_mean_vs_rmse():
    # Identity rotations: the w2c translation is minus the centre (a point reflection of both
    # sets, which preserves the aligned residuals), so legacy = mean of d,d,d,d,0 = 4d/5.
    ref, est = _poses(SQUARE), _poses(LIFTED)
    ref_w2c = np.stack([invert_pose(p) for p in ref])
    est_w2c = np.stack([invert_pose(p) for p in est])
    assert ate_mean_legacy(est_w2c, ref_w2c) == pytest.approx(4 * D / 5, abs=1e-12)
    assert ate_rmse(est, ref) == pytest.approx(2 * D / np.sqrt(5), abs=1e-12)
    assert ate_mean_legacy(est_w2c, ref_w2c) < ate_rmse(est, ref)
    # With rotating cameras, w2c translations (-R^T c) are not the centres: the numbers diverge.
    rots = [_rot([0, 1, 0], a) for a in (0, 20, 40, 60, 80)]
    ref_r, est_r = _poses(SQUARE, rots), _poses(LIFTED, rots)
    legacy = ate_mean_legacy(np.stack([invert_pose(p) for p in est_r]),
                             np.stack([invert_pose(p) for p in ref_r]))
    assert ate_rmse(est_r, ref_r) == pytest.approx(2 * D / np.sqrt(5), abs=1e-12)
    assert abs(legacy - 4 * D / 5) > 1e-4


def test_ate_skips_frames_without_reference():
    ref, est = _poses(SQUARE), _poses(LIFTED)
    ref = np.concatenate([ref, np.full((1, 4, 4), np.nan)])
    est = np.concatenate([est, _poses([[50.0, 50.0, 50.0]])])   # garbage where there is no reference
    assert ate_rmse(est, ref) == pytest.approx(D * np.sqrt(4 / 5), abs=1e-12)
    ref_w2c = np.concatenate([np.stack([invert_pose(p) for p in _poses(SQUARE)]), np.full((1, 4, 4), np.nan)])
    est_w2c = np.stack([invert_pose(p) for p in est])
    assert ate_mean_legacy(est_w2c, ref_w2c) == pytest.approx(4 * D / 5, abs=1e-12)
    assert np.isnan(ate_rmse(est[:1], np.full((1, 4, 4), np.nan)))
    with pytest.raises(ValueError):
        ate_rmse(est[:3], ref[:4])
    # Torch input.
    assert ate_rmse(torch.tensor(est), torch.tensor(ref)) == pytest.approx(D * np.sqrt(4 / 5), abs=1e-12)


def _walk(rng, n, offset):
    """A random walk of camera centres far from the world's origin (so sums about it would lose digits)."""
    return _poses(np.cumsum(rng.normal(0, 0.03, (n, 3)), axis=0) + offset)


def test_running_ate_equals_ate_rmse_as_the_trajectory_grows_and_moves():
    rng = np.random.default_rng(4)
    ref = _walk(rng, 400, [40.0, -25.0, 3.0])
    est = ref.copy()
    est[:, :3, 3] = (est[:, :3, 3] + rng.normal(0, 0.01, (400, 3))) @ _rot([1, 2, 3], 40).T + [5.0, 1.0, 0.0]
    ref[::9] = np.nan                      # frames without a reference pose
    running = RunningAte()
    assert running(est[:2], ref[:2]) is None and running(est[:0], ref[:0]) is None    # fewer than two pairs
    for n in range(3, 400, 7):
        assert running(est[:n], ref[:n]) == pytest.approx(ate_rmse(est[:n], ref[:n]), rel=1e-7)
    # poses an engine moved afterwards: a few (their pairs replaced in the sums), then many (rebuilt)
    for moved in (slice(100, 105), slice(0, 300)):
        est = est.copy()
        est[moved, :3, 3] += [0.02, -0.01, 0.03]
        assert running(est, ref) == pytest.approx(ate_rmse(est, ref), rel=1e-7)
    # a shorter trajectory (a resume) and an estimate that is not finite, as ate_rmse says
    assert running(est[:50], ref[:50]) == pytest.approx(ate_rmse(est[:50], ref[:50]), rel=1e-7)
    est[60, 0, 3] = np.nan
    assert np.isnan(running(est[:80], ref[:80])) and np.isnan(ate_rmse(est[:80], ref[:80]))
    est[60, 0, 3] = 0.0
    assert running(est[:80], ref[:80]) == pytest.approx(ate_rmse(est[:80], ref[:80]), rel=1e-7)


def test_running_ate_of_an_exact_trajectory_is_zero_to_rounding():
    ref = _walk(np.random.default_rng(5), 300, [1000.0, 0.0, 0.0])
    est = ref.copy()
    est[:, :3, 3] = est[:, :3, 3] @ _rot([0, 0, 1], 70).T - [300.0, 20.0, 0.0]
    running = RunningAte()
    assert running(est, ref) < 1e-6            # metres: no digits lost to the kilometre offsets


def test_relative_pose_errors():
    ref = _poses(SQUARE, [_rot([0, 0, 1], 10 * i) for i in range(5)])
    trans, rot = relative_pose_errors(ref, ref)
    np.testing.assert_allclose(trans, 0, atol=1e-12)
    np.testing.assert_allclose(rot, 0, atol=1e-6)
    est = ref.copy()
    est[3:, :3, 3] += [0.1, 0, 0]            # a 10 cm jump between frames 2 and 3
    trans, _ = relative_pose_errors(est, ref)
    np.testing.assert_allclose(trans, [0, 0, 0.1, 0], atol=1e-12)


def test_psnr_constant_error():
    target = np.full((8, 9, 3), 0.5)
    assert psnr(target + 0.1, target) == pytest.approx(20.0)          # MSE 0.01
    assert psnr(target - 0.01, target) == pytest.approx(40.0)
    assert psnr(target, target) == float("inf")
    # Not clamped: a prediction above 1 still counts its full error.
    assert psnr(np.full((2, 2), 1.5), np.ones((2, 2))) == pytest.approx(20 * np.log10(2.0))
    # Masked: only selected pixels count.
    pred = target.copy()
    pred[0] += 0.3
    mask = np.ones((8, 9), dtype=bool)
    mask[0] = False
    assert psnr(pred, target, mask) == float("inf")
    assert psnr(torch.tensor(target + 0.1), torch.tensor(target)) == pytest.approx(20.0)


def test_ssim_metric_accepts_numpy_and_torch():
    rng = np.random.default_rng(3)
    img = rng.random((20, 20, 3)).astype(np.float32)
    assert ssim_metric(img, img) == pytest.approx(1.0, abs=1e-6)
    noisy = np.clip(img + 0.1 * rng.normal(size=img.shape), 0, 1).astype(np.float32)
    s = ssim_metric(torch.tensor(noisy), img)
    assert 0 < s < 1 and s == pytest.approx(ssim_metric(noisy, img), abs=1e-6)


def test_depth_l1_ignores_invalid_target_pixels():
    target = np.array([[1.0, 2.0], [0.0, np.nan]])
    pred = np.array([[1.5, 1.0], [9.0, 9.0]])
    assert depth_l1(pred, target) == pytest.approx((0.5 + 1.0) / 2)
    assert depth_l1(torch.tensor(pred), torch.tensor(target)) == pytest.approx(0.75)
    assert np.isnan(depth_l1(pred, np.zeros((2, 2))))


def test_sim3_alignment_undoes_a_scale_that_se3_cannot():
    # A reference 8 % larger than the estimate (the 7-Scenes SfM pseudo ground truth against depth),
    # turned and moved: Sim(3) recovers it exactly, SE(3) leaves the scale's error.
    from splat_core.metrics import align_similarity, ate_errors

    rng = np.random.default_rng(3)
    est = np.stack([pose_matrix(quat_to_rotmat_np(np.r_[1.0, 0.1 * rng.normal(size=3)] /
                                                  np.linalg.norm(np.r_[1.0, 0.1 * rng.normal(size=3)])),
                                rng.normal(size=3)) for _ in range(30)])
    R = quat_to_rotmat_np(np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2]))
    ref = est.copy()
    ref[:, :3, 3] = 1.08 * est[:, :3, 3] @ R.T + np.array([0.5, -1.0, 2.0])
    s, R_found, t = align_similarity(est[:, :3, 3], ref[:, :3, 3])
    assert np.isclose(s, 1.08) and np.allclose(R_found, R) and np.allclose(t, [0.5, -1.0, 2.0])
    assert ate_errors(est, ref, scale=True).max() < 1e-9 and ate_errors(est, ref).max() > 0.01


def test_three_lenses_cuts_pieces_and_splits_where_the_reference_breaks():
    from three_lenses import reference_rows

    t = np.arange(40)
    est = np.stack([pose_matrix(np.eye(3), [0.01 * k, 0, 0]) for k in t])
    ref = est.copy()
    ref[25:, 0, 3] += 0.05                    # the reference jumps 5 cm at step 24 -> 25
    rows = reference_rows(est, t, ref, piece=20, breaks=[24])
    assert rows["split_se3_cm"] < 1e-6 < rows["whole_se3_cm"]
    assert [p["frames"] for p in rows["pieces"]] == ["0-19", "20-39"]
    assert rows["pieces"][0]["se3_cm"] < 1e-6 < rows["pieces"][1]["se3_cm"]


def test_three_lenses_reports_the_largest_error_and_who_departs_there():
    from three_lenses import local_check, reference_rows

    t = np.arange(60)
    est = np.stack([pose_matrix(np.eye(3), [0.01 * k, 0.002 * k, 0]) for k in t])
    kf, sfm = est.copy(), est.copy()
    kf[30:33, 1, 3] += 0.05                   # the first reference alone leaves for three frames
    sfm[:, :3, 3] *= 1.08                     # the second one agrees up to its scale
    rows = reference_rows(est, t, kf, piece=20, breaks=[])
    assert rows["whole_se3_max"]["frame"] in (30, 31, 32) and rows["whole_se3_max"]["cm"] > 3
    assert [p["se3_max"]["frame"] in (30, 31, 32) for p in rows["pieces"]] == [False, True, False]
    refs = {"kinectfusion": kf, "sfm": sfm}
    here = local_check(est, refs, 31)
    assert here["window"] == "21-41"
    assert here["run_vs_kinectfusion_cm"] > 3 and here["kinectfusion_vs_sfm_cm"] > 3
    assert here["run_vs_sfm_cm"] < 1e-6          # Sim(3): the run departs from neither
    refs["sfm"][31] = np.nan                      # a frame a reference lacks is left out
    assert "run_vs_sfm_cm" not in local_check(est, refs, 31)
