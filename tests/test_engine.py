"""SplaTAM engine modules on small synthetic scenes (ray-cast, independent of our renderer)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from splat_core.camera import (Intrinsics, backproject, invert_pose, pose_matrix, predict_constant_velocity,
                               project, quat_to_rotmat_np, rotmat_to_quat)
from splat_core.config import (DensifyConfig, KeyframeConfig, MappingConfig, TrackingConfig, load_config)
from splat_core.densify import gaussians_from_pixels, new_pixel_mask
from splat_core.gaussians import GaussianMap
from splat_core.keyframes import KeyframeStore, is_keyframe_time, overlap_scores
from splat_core.mapping import View, frustum_mask, optimise_map, prune_mask
from splat_core.render import render
from splat_core.synthetic import SyntheticSource
from splat_core.render import Renderer
from splat_core.tracking import Candidate, Observation, Tracker, candidate, polish


def small_source(n=12, w=80, h=60, **kw):
    return SyntheticSource(n_frames=n, width=w, height=h, seed=3, **kw)


def map_from_frame(frame, w2c=np.eye(4)):
    mask = frame.depth > 0
    return gaussians_from_pixels(frame.color, frame.depth, mask, frame.intrinsics, w2c, 0, DensifyConfig(), True)


def rel_w2c(src, i):
    """Reference w2c of frame i in the world of frame 0 (the SLAM world)."""
    return invert_pose(invert_pose(src[0].c2w_ref) @ src[i].c2w_ref)


# ----------------------------------------------------------------------------- camera conventions

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


# ----------------------------------------------------------------------------- tracking

def _perturbed_tracking_case():
    """(map, frame 1, true w2c, a start 1.4 cm off). The map comes from frame 0 after mapping (an
    unoptimised map of 1-px Gaussians renders depth biased towards the camera; mapping removes most
    of it)."""
    src = small_source(n=2, w=160, h=120)
    f0, f1 = src[0], src[1]
    m = map_from_frame(f0)
    view = View(torch.as_tensor(f0.color), torch.as_tensor(f0.depth), np.eye(4))
    optimise_map(m, [view], f0.intrinsics, MappingConfig(), 150, 2.0, np.random.default_rng(0))
    truth = rel_w2c(src, 1)
    return m, f1, truth, pose_matrix(np.eye(3), (0.01, -0.005, 0.008)) @ truth


def _centre_error(w2c, truth) -> float:
    return float(np.linalg.norm(invert_pose(w2c)[:3, 3] - invert_pose(truth)[:3, 3]))


def test_tracking_recovers_a_perturbed_pose():
    m, f1, truth, start = _perturbed_tracking_case()
    obs = Observation(f1.intrinsics, torch.as_tensor(f1.color), torch.as_tensor(f1.depth))
    out = polish(Renderer(), m.tensors(detach=True), obs, start, TrackingConfig(iterations=60))
    err = _centre_error(out.w2c, truth)
    assert err < 0.008 and err < _centre_error(start, truth) / 2
    assert out.iterations == 60 and out.valid_pixels > 0


@pytest.mark.parametrize("rule", ["random", "gradient"])
def test_sparse_tracking_recovers_a_perturbed_pose_like_dense_tracking(rule):
    # The previous test's setting, tracked on one pixel per 4 x 4 block through the sparse renderer.
    m, f1, truth, start = _perturbed_tracking_case()
    errors = {}
    for pixels in ("all", rule):
        config = TrackingConfig(iterations=60, pixels=pixels, pixel_tile=4, min_pixels=1)
        out = Tracker(config, f1.intrinsics, Renderer()).track(m.tensors(detach=True), f1.color, f1.depth, start)
        errors[pixels] = _centre_error(out.w2c, truth)
        assert out.iterations == 60 and out.valid_pixels > 0
    assert errors[rule] < 0.008 and errors[rule] < 1.5 * errors["all"] + 0.001, errors


def test_tracking_keeps_the_best_pose_not_the_last():
    src = small_source(n=1, w=64, h=48)
    f0 = src[0]
    m = map_from_frame(f0)
    # A huge learning rate makes later steps diverge; the best (initial, exact) pose must be kept.
    cfg = TrackingConfig(iterations=5, lr_rotation=0.5, lr_translation=0.5)
    obs = Observation(f0.intrinsics, torch.as_tensor(f0.color), torch.as_tensor(f0.depth))
    out = polish(Renderer(), m.tensors(detach=True), obs, np.eye(4), cfg)
    assert np.allclose(out.w2c, np.eye(4), atol=1e-6)


# ----------------------------------------------------------------------------- densification

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


# ----------------------------------------------------------------------------- mapping and pruning

def test_pruning_removes_transparent_and_huge_gaussians_and_keeps_adam_state_aligned():
    m = GaussianMap.from_points(np.zeros((5, 3)) + [0, 0, 2], np.full((5, 3), 0.5), np.full(5, 0.01), 0)
    with torch.no_grad():
        m.logit_opacities[1] = -8.0                     # opacity 3e-4 < 0.005
        m.log_scales[3] = np.log(0.5)                   # > 0.1 * scene radius 1.0
    keep = prune_mask(m, MappingConfig(), scene_radius=1.0)
    assert keep.tolist() == [True, False, True, False, True]
    opt = torch.optim.Adam(m.param_groups(MappingConfig().lrs))
    (m.means.sum() + m.colors.sum()).backward()
    opt.step()
    marker = opt.state[m.means]["exp_avg"].clone()
    marker[:, 0] = torch.arange(5.0)
    opt.state[m.means]["exp_avg"] = marker
    assert m.prune(keep, opt) == 2
    assert len(m) == 3 and opt.state[m.means]["exp_avg"][:, 0].tolist() == [0.0, 2.0, 4.0]
    assert opt.param_groups[0]["params"][0] is m.means


@pytest.mark.parametrize("tile_fraction", [1.0, 0.5])
def test_mapping_reduces_the_loss_and_leaves_unseen_gaussians_untouched(tile_fraction):
    src = small_source(n=1, w=64, h=48)
    f = src[0]
    m = map_from_frame(f)
    far = GaussianMap.from_points([[0, 0, -5.0]], [[1, 0, 0]], [0.01], 0)   # behind the camera
    m.append(far)
    with torch.no_grad():
        m.colors[:-1] += 0.2                       # spoil the colours
    view = View(torch.as_tensor(f.color), torch.as_tensor(f.depth), np.eye(4))
    cfg = MappingConfig(tile_fraction=tile_fraction, min_tiles=0)
    from splat_core.mapping import mapping_loss
    before = float(mapping_loss(render(m, f.intrinsics, np.eye(4)), view, cfg))
    far_before = m.means[-1].detach().clone()
    stats = optimise_map(m, [view], f.intrinsics, cfg, round(15 / tile_fraction), scene_radius=2.0,
                         rng=np.random.default_rng(0))
    after = float(mapping_loss(render(m, f.intrinsics, np.eye(4)), view, cfg))
    assert after < 0.8 * before
    assert torch.equal(m.means[-1].detach(), far_before)
    assert stats["optimised"] == len(m) - 1


def test_first_frame_maps_every_tile(monkeypatch):
    """Frame 0 anchors the trajectory: its long first mapping draws every tile; later frames draw
    the configured fraction."""
    import splat_core.slam as slam_module
    seen = []
    monkeypatch.setattr(slam_module, "optimise_map",
                        lambda m, window, intr, config, iterations, *a, **k: seen.append(
                            (config.tile_fraction, iterations)) or {"pruned": 0})
    cfg = load_config("cpu")
    assert cfg.mapping.tile_fraction < 1
    src = small_source(n=2)
    slam = slam_module.SplaTAM(cfg, src.intrinsics)
    slam.optimise([], first=True)
    slam.optimise([], first=False)
    assert seen == [(1.0, cfg.mapping.first_frame_iterations), (cfg.mapping.tile_fraction, cfg.mapping.iterations)]


def test_mapping_loss_over_drawn_tiles():
    """Over every pixel the tile loss is the full loss; over some tiles it sees those tiles only."""
    from splat_core.mapping import draw_tiles, mapping_loss
    src = small_source(n=2, w=64, h=48)
    f, g = src[0], src[1]
    rendered = render(map_from_frame(f), f.intrinsics, np.eye(4))
    view = View(torch.as_tensor(g.color), torch.as_tensor(g.depth), np.eye(4))
    cfg = MappingConfig()
    full = float(mapping_loss(rendered, view, cfg))
    everything = torch.ones(f.intrinsics.height, f.intrinsics.width, dtype=torch.bool)
    assert float(mapping_loss(rendered, view, cfg, everything)) == pytest.approx(full, rel=1e-5)
    tiles, pixels = draw_tiles(f.intrinsics, 0.5, np.random.default_rng(0))
    assert tiles.shape == (3, 4) and int(tiles.sum()) == 6 and int(pixels.sum()) == 6 * 16 * 16
    spoilt = rendered._replace(color=torch.where(pixels[..., None], rendered.color, 1 - rendered.color))
    assert float(mapping_loss(spoilt, view, cfg, pixels)) == pytest.approx(float(mapping_loss(rendered, view, cfg, pixels)),
                                                                         rel=1e-2)
    assert float(mapping_loss(spoilt, view, cfg)) > 1.2 * full
    assert draw_tiles(f.intrinsics, 1.0, np.random.default_rng(0)) == (None, None)
    assert int(draw_tiles(f.intrinsics, 0.5, np.random.default_rng(0), min_tiles=8)[0].sum()) == 8
    assert draw_tiles(f.intrinsics, 0.5, np.random.default_rng(0), min_tiles=12) == (None, None)   # small images: all


def test_frustum_mask_is_conservative():
    intr = Intrinsics(60, 60, 31.5, 23.5, 64, 48)
    rng = np.random.default_rng(0)
    pts = rng.uniform([-3, -3, -1], [3, 3, 4], (3000, 3))
    g = GaussianMap.from_points(pts, rng.uniform(0, 1, (3000, 3)), rng.uniform(0.005, 0.05, 3000), 0)
    keep = frustum_mask(g.means.detach(), g.log_scales.detach(), intr, np.eye(4), 0.01)
    out = render(g, intr, np.eye(4))
    g.means.grad = None
    out.color.sum().backward()
    touched = g.means.grad.abs().sum(1) > 0
    assert bool((keep | ~touched).all()) and keep.sum() < 3000


# ----------------------------------------------------------------------------- keyframes

def test_keyframe_schedule():
    assert [t for t in range(12) if is_keyframe_time(t, 12, 5)] == [0, 4, 9, 10]


def test_overlap_scores_and_window_selection():
    src = small_source(n=1, w=64, h=48)
    f = src[0]
    intr = f.intrinsics
    turned = pose_matrix(quat_to_rotmat_np([np.cos(0.25), 0, np.sin(0.25), 0]), [0, 0, 0])  # 29 deg yaw
    behind = pose_matrix(quat_to_rotmat_np([0, 0, 1, 0]), [0, 0, 0])                       # 180 deg
    store = KeyframeStore(KeyframeConfig(overlap_border=2), intr)      # a 64x48 image: small border
    for i, w2c in enumerate([behind, np.eye(4), turned, behind]):
        store.add(i, w2c, f.color, f.depth)
    scores = overlap_scores(f.depth, np.eye(4), intr, store.items[:-1], np.random.default_rng(0), border=2)
    assert scores[1] > 0.8 and 0 < scores[2] < scores[1] and scores[0] == 0
    window = store.select(f.depth, np.eye(4), k=3, rng=np.random.default_rng(0))
    assert [kf.frame_index for kf in window] == [1, 2, 3]      # top overlaps, then the latest
    window = store.select(f.depth, np.eye(4), k=2, rng=np.random.default_rng(0))
    assert [kf.frame_index for kf in window] == [1, 3]


def test_overlap_within_depth_drops_keyframes_that_never_measured_the_view():
    # A keyframe far back on the same line of sight projects today's points inside its image
    # (SplaTAM's test counts it), but they lie beyond the farthest depth it measured.
    src = small_source(n=1, w=64, h=48)
    f = src[0]
    intr = f.intrinsics
    far = float(f.depth.max())
    back = pose_matrix(np.eye(3), [0, 0, 3 * far])               # w2c: the camera 3 x far behind
    near_back = pose_matrix(np.eye(3), [0, 0, 0.02 * far])
    store = KeyframeStore(KeyframeConfig(overlap_border=2), intr)
    for i, w2c in enumerate([back, near_back]):
        store.add(i, w2c, f.color, f.depth)
    def scores(within):
        return overlap_scores(f.depth, np.eye(4), intr, store.items, np.random.default_rng(0), 1600, 2, within)
    plain, ranged = scores(False), scores(True)
    assert plain[0] > 0.5 and ranged[0] == 0.0
    assert ranged[1] == pytest.approx(plain[1]) and ranged[1] > 0.5


# ----------------------------------------------------------------------------- whole pipeline

@pytest.mark.slow
def test_slam_on_a_synthetic_sequence_tracks_to_under_a_centimetre():
    # The cpu preset as shipped (320x240) on the benchmark's scene (seed 0). Lower resolutions bias
    # the rendered depth of a map of one-pixel Gaussians and give 1-2 cm; so does the harder camera
    # path of seed 3 (1.8 cm, see README) - a known limit, not hidden by this test.
    from splat_core.pipeline import Pipeline
    pipe = Pipeline(SyntheticSource(n_frames=8, width=320, height=240, seed=0), load_config("cpu"))
    while pipe.step() is not None:
        pass
    assert pipe.ate_cm() < 1.0
    assert len(pipe.slam.keyframes) == 3          # frames 0, 4, 6 (second to last)
    assert len(pipe.slam.map) > 70000


# ----------------------------------------------------------------------------- direct alignment

def _aligned_level(frame):
    """A pyramid level whose 'rendering' is the frame's own depth and grey levels."""
    from splat_core.direct_align import _grey, _Level
    valid = frame.depth > 0
    return _Level(frame.intrinsics, frame.depth.astype(np.float64), _grey(frame.color.astype(np.float64)), valid,
                  frame.depth.astype(np.float64), _grey(frame.color.astype(np.float64)))


def test_direct_alignment_jacobians_match_finite_differences():
    from splat_core.direct_align import _linearise, _se3_exp
    f0 = small_source(n=1, w=80, h=60)[0]
    lvl = _aligned_level(f0)
    i = lvl.intr
    # A grey ramp: its bilinear samples and its (Sobel) gradient are exact, so the colour Jacobian's
    # chain rule is checked, not the image-gradient approximation.
    u, v = np.meshgrid(np.arange(i.width, dtype=np.float64), np.arange(i.height, dtype=np.float64))
    lvl.model_grey = 0.01 * u - 0.02 * v
    lvl.model_grad = np.ascontiguousarray(np.broadcast_to([0.01, -0.02], (i.height, i.width, 2)))
    X0 = _se3_exp(np.array([0.004, -0.003, 0.002, 0.003, -0.002, 0.004]))

    def lin(X):
        return _linearise(lvl.live_points, lvl.live_grey, X, i.fx, i.fy, i.cx, i.cy, lvl.model_points,
                          lvl.model_normals, lvl.model_ok, lvl.model_grey, lvl.model_grad, lvl.color_ok, 0.1)
    r_d, J_d, ok_d, r_c, J_c, ok_c = lin(X0)
    eps = 1e-6
    for k in range(6):
        xi = np.zeros(6)
        xi[k] = eps
        rp, _, okp, rcp, _, okcp = lin(_se3_exp(xi) @ X0)
        rm, _, okm, rcm, _, okcm = lin(_se3_exp(-xi) @ X0)
        # Nearest-pixel association fixes the plane; keep points whose pixel did not change.
        same = ok_d & okp & okm
        fd = (rp - rm)[same] / (2 * eps)
        assert np.allclose(fd, J_d[same, k], rtol=1e-3, atol=1e-6 * np.abs(J_d[:, k]).max())
        same_c = ok_c & okcp & okcm
        fd_c = (rcp - rcm)[same_c] / (2 * eps)
        assert np.allclose(fd_c, J_c[same_c, k], rtol=1e-3, atol=1e-6 * np.abs(J_c[:, k]).max())


def _align_frame_to_frame(seed: int, depth_noise: bool) -> float:
    """Translation error (mm) of frame 2 (depth noise 3 mm x z^2) aligned to frame 0's exact depth."""
    from splat_core.direct_align import _gauss_newton_step, _grey, _Level
    f0 = SyntheticSource(n_frames=3, width=160, height=120, seed=seed)[0]
    f2 = SyntheticSource(n_frames=3, width=160, height=120, seed=seed, noise=0.003)[2]
    d0, d2 = f0.depth.astype(np.float64), f2.depth.astype(np.float64)
    lvl = _Level(f0.intrinsics, d0, _grey(f0.color.astype(np.float64)), d0 > 0, d2, _grey(f2.color.astype(np.float64)))
    X = np.eye(4)
    for _ in range(20):
        X = _gauss_newton_step(lvl, X, 0.0, 0.1, depth_noise)[0] @ X
    truth = invert_pose(f0.c2w_ref) @ f2.c2w_ref          # live camera -> model camera
    return 1000 * float(np.linalg.norm((invert_pose(truth) @ X)[:3, 3]))


def test_depth_noise_weighting_helps_when_far_depth_is_noisy():
    # Six rooms (depth 0.5-6.3 m): about 1.5 mm unweighted, 0.85 mm weighted on average; one of the
    # six (seed 1) is worse weighted, so the claim is about the average.
    plain = np.mean([_align_frame_to_frame(seed, False) for seed in range(6)])
    weighted = np.mean([_align_frame_to_frame(seed, True) for seed in range(6)])
    assert weighted < 0.75 * plain, (weighted, plain)


def test_direct_alignment_recovers_a_large_offset():
    from splat_core.direct_align import align_to_map
    # Seed 0's scene: on seed 3's, 60 mapping iterations at 160x120 leave the map's depth biased
    # (the alignment then lands 1-1.5 cm off; 200 iterations bring it back to 0.3 cm).
    src = SyntheticSource(n_frames=4, width=160, height=120, seed=0)
    f0 = src[0]
    m = map_from_frame(f0)
    view = View(torch.as_tensor(f0.color), torch.as_tensor(f0.depth), np.eye(4))
    optimise_map(m, [view], f0.intrinsics, MappingConfig(), 60, 2.0, np.random.default_rng(0))
    truth = rel_w2c(src, 3)
    start = np.eye(4)                       # the frame is several centimetres from frame 0
    centre = lambda w2c: invert_pose(w2c)[:3, 3]  # noqa: E731
    err0 = np.linalg.norm(centre(start) - centre(truth))
    out = align_to_map(m.tensors(detach=True), src[3].color, src[3].depth, src[3].intrinsics, start,
                       iterations=10, passes=2)
    err = np.linalg.norm(centre(out.w2c) - centre(truth))
    assert err0 > 0.03 and err < 0.005
    assert out.correspondences > 1000


def test_direct_alignment_keeps_the_start_when_the_map_is_out_of_view():
    from splat_core.direct_align import align_to_map
    f0 = small_source(n=1, w=64, h=48)[0]
    m = map_from_frame(f0)
    away = pose_matrix(quat_to_rotmat_np([0.0, 0.0, 1.0, 0.0]), (0.0, 0.0, 0.0))   # looking backwards
    out = align_to_map(m.tensors(detach=True), f0.color, f0.depth, f0.intrinsics, away)
    assert np.array_equal(out.w2c, away) and out.correspondences < 50


def test_tracking_rejects_an_alignment_that_raises_the_loss(monkeypatch):
    import splat_core.tracking as tracking_module
    from splat_core.slam import SplaTAM
    src = small_source(n=2, w=80, h=60)
    cfg = load_config("cpu", overrides={"resolution": [80, 60], "tracking": {"iterations": 0},
                                        "mapping": {"first_frame_iterations": 20}})
    slam = SplaTAM(cfg, src[0].intrinsics)
    slam.process(src[0])
    truth = rel_w2c(src, 1)
    wrong = pose_matrix(np.eye(3), (0.05, 0.0, 0.0)) @ truth
    real_align = tracking_module.align_to_map

    def align_returning(w2c):
        return lambda *a, **k: dataclasses.replace(real_align(*a, **k), w2c=w2c)

    g = slam.map.tensors(detach=True)
    monkeypatch.setattr(tracking_module, "align_to_map", align_returning(wrong))
    out = slam.tracker.track(g, src[1].color, src[1].depth, truth)
    assert np.array_equal(out.w2c, truth) and out.start == "prediction"
    monkeypatch.setattr(tracking_module, "align_to_map", align_returning(truth))
    out = slam.tracker.track(g, src[1].color, src[1].depth, wrong)
    assert np.array_equal(out.w2c, truth) and out.start == "aligned"


def test_tracking_starts_from_the_rival_when_the_start_is_worse():
    # The acceptance check riding on Adam's first iteration (tracking.polish's `rival`).
    src = small_source(n=2, w=80, h=60)
    m = map_from_frame(src[0])
    f1, truth = src[1], rel_w2c(src, 1)
    wrong = pose_matrix(np.eye(3), (0.05, 0.0, 0.0)) @ truth
    cfg = TrackingConfig(iterations=1)
    obs = Observation(f1.intrinsics, torch.as_tensor(f1.color), torch.as_tensor(f1.depth))
    g, renderer = m.tensors(detach=True), Renderer()
    at_truth = candidate("prediction", truth, obs.render(renderer, g, truth), obs, cfg)
    at_wrong = candidate("prediction", wrong, obs.render(renderer, g, wrong), obs, cfg)
    # One iteration returns the pose it evaluated before stepping: the rival when the start is worse...
    out = polish(renderer, g, obs, Candidate("aligned", wrong, np.nan, 0), cfg, rival=at_truth)
    assert np.allclose(out.w2c, truth, atol=1e-6) and out.iterations == 1 and out.start == "prediction"
    # ... and the start when it is better.
    out = polish(renderer, g, obs, Candidate("aligned", truth, np.nan, 0), cfg, rival=at_wrong)
    assert np.allclose(out.w2c, truth, atol=1e-6) and out.start == "aligned"


@pytest.mark.cuda
@pytest.mark.slow
def test_slam_on_cuda_tracks_like_the_cpu():
    # The whole engine on the GPU (gsplat renderer, tensors on the device, keyframes on the host).
    from splat_core.pipeline import Pipeline
    from splat_core.render import cuda
    reason = cuda.unavailable_reason()
    if reason is not None:
        pytest.skip(f"CUDA backend unavailable: {reason}")
    pipe = Pipeline(SyntheticSource(n_frames=8, width=320, height=240, seed=0), load_config("splatam_s"),
                    device="cuda")
    while pipe.step() is not None:
        pass
    assert pipe.slam.map.device.type == "cuda"
    assert pipe.ate_cm() < 1.0


def test_keyframes_are_compact_and_spill_to_their_file_unchanged(tmp_path):
    f = small_source(n=1, w=64, h=48, noise=0.002)[0]
    store = KeyframeStore(KeyframeConfig(memory_mb=0.02), f.intrinsics)     # room for one 64x48 keyframe
    store.attach(tmp_path / "keyframes.bin")
    for i in range(3):
        store.add(i, np.eye(4), f.color, f.depth)
    assert store.resident_bytes() == 64 * 48 * 5                              # uint8 colour + uint16 depth
    assert [kf.resident for kf in store] == [False, False, True]
    assert (tmp_path / "keyframes.bin").stat().st_size == 3 * 64 * 48 * 5
    for kf in store:                                                          # read back from the file
        assert kf.color.dtype == np.float32 and np.abs(kf.color - f.color).max() <= 0.5 / 255 + 1e-7
        assert np.abs(kf.depth - f.depth).max() <= 0.5 * f.depth.max() / 65535 + 1e-6
        assert np.array_equal(kf.depth > 0, f.depth > 0)
    # A resumed store reads the checkpoint's records and drops what was appended after them.
    arrays = store.to_arrays()
    store.add(3, np.eye(4), f.color, f.depth)
    again = KeyframeStore(KeyframeConfig(memory_mb=0.02), f.intrinsics)
    again.load_arrays(arrays, tmp_path / "keyframes.bin")
    assert len(again) == 3 and (tmp_path / "keyframes.bin").stat().st_size == 3 * 64 * 48 * 5
    assert all(np.array_equal(a.depth, b.depth) and np.array_equal(a.color, b.color) for a, b in zip(store, again))


def test_keyframes_spill_without_a_run_folder():
    f = small_source(n=1, w=64, h=48)[0]
    store = KeyframeStore(KeyframeConfig(memory_mb=0), f.intrinsics)
    kf = store.add(0, np.eye(4), f.color, f.depth)
    assert store.resident_bytes() == 0 and not kf.resident
    assert np.abs(kf.color - f.color).max() <= 0.5 / 255 + 1e-7
    store.close()                                                             # back in memory, still readable
    assert kf.resident and np.abs(kf.color - f.color).max() <= 0.5 / 255 + 1e-7


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("drawn", [False, True])
def test_cpu_mapping_loss_equals_the_torch_definition(dtype, drawn):
    """mapping_loss on CPU tensors (mapping_loss_cpu: one autograd step) has the value and the
    gradients of the torch definition, with and without drawn tiles, with pixels without depth
    and residuals that are exactly 0 (|x| has gradient 0 there, as in torch)."""
    from splat_core.mapping import _mapping_loss_torch, draw_tiles, mapping_loss
    from splat_core.render import Render
    g = torch.Generator().manual_seed(0)
    H, W = 48, 64
    view = View(torch.rand(H, W, 3, generator=g, dtype=dtype), 1 + torch.rand(H, W, generator=g, dtype=dtype), np.eye(4))
    view.depth[:10, :20] = 0                                   # no depth here
    color = torch.rand(H, W, 3, generator=g, dtype=dtype)
    depth = 1 + torch.rand(H, W, generator=g, dtype=dtype)
    color[5, 5] = view.color[5, 5]                             # exact matches: zero residuals
    depth[30, 30] = view.depth[30, 30]
    intr = Intrinsics(fx=60.0, fy=60.0, cx=32.0, cy=24.0, width=W, height=H)
    pixels = draw_tiles(intr, 0.5, np.random.default_rng(1))[1] if drawn else None
    cfg = MappingConfig()
    results = []
    for loss_fn in (mapping_loss, _mapping_loss_torch):
        c, d = color.clone().requires_grad_(), depth.clone().requires_grad_()
        loss = loss_fn(Render(c, d, torch.ones(H, W, dtype=dtype)), view, cfg, pixels)
        loss.backward()
        results.append((float(loss), c.grad, d.grad))
    (v_cpu, gc_cpu, gd_cpu), (v_ref, gc_ref, gd_ref) = results
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    assert v_cpu == pytest.approx(v_ref, rel=tol)
    assert torch.allclose(gc_cpu, gc_ref, rtol=tol, atol=tol * float(gc_ref.abs().max()))
    assert torch.equal(gd_cpu, gd_ref) or torch.allclose(gd_cpu, gd_ref, rtol=tol, atol=0)
    assert gd_cpu[30, 30] == 0 and bool((gd_cpu[:10, :20] == 0).all())
