"""Tracking (tracking.py): a perturbed pose recovered, sparse pixels, best pose kept, alignment accepted or rejected."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from splat_core.camera import (invert_pose, pose_matrix)
from splat_core.config import (MappingConfig, TrackingConfig, load_config)
from splat_core.mapping import View, optimise_map
from splat_core.render import Renderer
from splat_core.tracking import Candidate, Observation, Tracker, candidate, polish

from helpers.engine import map_from_frame, rel_w2c, small_source


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


def test_a_reused_render_aligns_the_next_frame_as_a_fresh_one_does():
    """tracking.align.reuse_render: the second frame of a map version is aligned against the dense
    render made for the first (no render of its own: counted), from the render's pose, and lands
    where a fresh render puts it."""
    from splat_core.align import numba_backend
    m, f1, truth, start = _perturbed_tracking_case()
    config = dataclasses.replace(load_config("live").tracking, pixel_tile=4, min_pixels=1)
    gaussians = m.tensors(detach=True)           # one map version: the same object for both frames
    renders = []
    original = numba_backend.render

    def counted(*args, **kwargs):
        renders.append(1)
        return original(*args, **kwargs)
    numba_backend.render = counted
    try:
        tracker = Tracker(config, f1.intrinsics, Renderer())
        first = tracker.track(gaussians, f1.color, f1.depth, pose_matrix(np.eye(3), (0.02, 0.0, 0.0)) @ truth,
                              reuse=True)
        assert len(renders) == 1
        reused = tracker.track(gaussians, f1.color, f1.depth, start, reuse=True)
        assert len(renders) == 1                 # the first frame's render served the second
        fresh = Tracker(config, f1.intrinsics, Renderer()).track(gaussians, f1.color, f1.depth, start)
        assert len(renders) == 2
    finally:
        numba_backend.render = original
    assert _centre_error(first.w2c, truth) < 0.01
    assert _centre_error(reused.w2c, truth) < max(0.003, 1.5 * _centre_error(fresh.w2c, truth)), \
        (_centre_error(reused.w2c, truth), _centre_error(fresh.w2c, truth))


def test_a_reused_render_lends_its_pyramid_and_the_pose_is_the_same():
    """The frames aligned against a reused render share the arrays the alignment made from it on
    each pyramid level (AlignResult.first_pyramid, handed back as model[2]): they are not made
    again, and the pose is, bit for bit, the one the render alone gives. With `exposure` the
    render's grey levels depend on the live frame: no pyramid is handed out."""
    from splat_core.align import align_to_map, numba_backend
    m, f1, truth, start = _perturbed_tracking_case()
    gaussians = m.tensors(detach=True)
    made = []
    original = numba_backend._ModelSide

    class Counted(original):
        def __init__(self, *args, **kwargs):
            made.append(1)
            super().__init__(*args, **kwargs)
    rendered_at = pose_matrix(np.eye(3), (0.02, 0.0, 0.0)) @ truth
    numba_backend._ModelSide = Counted
    try:
        first = align_to_map(gaussians, f1.color, f1.depth, f1.intrinsics, rendered_at)
        assert len(made) == 3 and len(first.first_pyramid) == 3
        shared = align_to_map(gaussians, f1.color, f1.depth, f1.intrinsics, start,
                              model=(first.first_render, rendered_at, first.first_pyramid))
        assert len(made) == 3
        anew = align_to_map(gaussians, f1.color, f1.depth, f1.intrinsics, start,
                            model=(first.first_render, rendered_at))
        assert len(made) == 6
        lit = align_to_map(gaussians, f1.color, f1.depth, f1.intrinsics, start, exposure=True,
                           model=(first.first_render, rendered_at, first.first_pyramid))
        assert len(made) == 9 and lit.first_pyramid is None
    finally:
        numba_backend._ModelSide = original
    assert np.array_equal(shared.w2c, anew.w2c) and shared.correspondences == anew.correspondences
    assert shared.rmse_depth == anew.rmse_depth and _centre_error(shared.w2c, truth) < 0.01


@pytest.mark.parametrize("rival,beyond,scored", [(True, 0.0, True), (False, 0.0, False), (False, 0.01, True),
                                                 (False, 0.06, False)])
def test_an_alignment_against_a_reused_render_gone_astray_loses_to_the_prediction_only_when_scored(rival, beyond, scored):
    """tracking.align.reuse_rival: on a frame aligned against a reused render, an alignment gone
    astray (4 cm off, as the synthetic corridor's went looking down it) loses to a right prediction
    when the prediction is scored (true); unscored (false, the `live` preset's), it is kept, and on the
    corridor one such frame fed the motion model a wrong velocity and the live preset lost it at
    frames 241-255 (docs/benchmarks.md, "Long runs"). reuse_rival_beyond: scored anyway when the
    alignment moved the camera further than that from the prediction (here 4 cm: 1 cm scores it, 6 cm
    does not)."""
    m, f1, truth, _ = _perturbed_tracking_case()
    config = dataclasses.replace(load_config("live").tracking, pixel_tile=4, min_pixels=1)
    config = dataclasses.replace(config, align=dataclasses.replace(config.align, reuse_rival=rival,
                                                                   reuse_rival_beyond=beyond))
    gaussians = m.tensors(detach=True)           # one map version: the second frame reuses the render
    tracker = Tracker(config, f1.intrinsics, Renderer())
    aligned = tracker.align

    def astray(g, color, depth, w2c, model=None):
        out = aligned(g, color, depth, w2c, model)
        if model is not None:                     # only against the reused render
            out = dataclasses.replace(out, w2c=pose_matrix(np.eye(3), (0.0, 0.0, 0.04)) @ out.w2c)
        return out
    tracker.align = astray
    tracker.track(gaussians, f1.color, f1.depth, pose_matrix(np.eye(3), (0.01, 0.0, 0.0)) @ truth, reuse=True)
    assert tracker._model is not None            # the render is kept for the next frame
    out = tracker.track(gaussians, f1.color, f1.depth, truth, reuse=True)
    assert tracker._model is not None and tracker._model.uses == 1      # it was aligned against the reused render
    if scored:
        assert out.start == "prediction" and _centre_error(out.w2c, truth) < 0.005, (out.start, _centre_error(out.w2c, truth))
    else:
        assert out.start == "aligned" and _centre_error(out.w2c, truth) > 0.03, (out.start, _centre_error(out.w2c, truth))
