"""mapping.final_color_fit (color_fit.py): one gain and offset per channel over the keyframes,
applied to the map's colours; the run's poses untouched."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

from splat_core.camera import Intrinsics, invert_pose
from splat_core.color_fit import ColorFit, fit_map_colors
from splat_core.config import load_config
from splat_core.render import Renderer
from splat_core.run import Pipeline
from splat_core.synthetic import SyntheticSource
from tests.helpers.maps import oblique_camera, two_walls

INTR = Intrinsics(fx=60.0, fy=60.0, cx=40.0, cy=30.0, width=80, height=60)


def _views(gmap, renderer, gain, offset):
    """Keyframe-like views whose colours are the map's render under a known gain and offset."""
    views = []
    for c2w in (np.eye(4), oblique_camera()):
        w2c = invert_pose(c2w)
        with torch.no_grad():
            out = renderer.render_visible(gmap.tensors(detach=True), INTR, w2c)
        color = out.color.numpy() * gain + offset * out.alpha.numpy().reshape(60, 80, 1)
        views.append(SimpleNamespace(color=color, w2c=w2c))
    return views


def test_fit_recovers_a_known_gain_and_offset_and_the_renders_then_match():
    gmap, renderer = two_walls(), Renderer()
    gain, offset = np.array([1.3, 0.9, 1.1]), np.array([0.05, -0.02, 0.0])
    views = _views(gmap, renderer, gain, offset)
    record = fit_map_colors(gmap, views, INTR, renderer)
    assert record["keyframes"] == 2
    np.testing.assert_allclose(record["gain"], gain, atol=1e-4)
    np.testing.assert_allclose(record["offset"], offset, atol=1e-4)
    with torch.no_grad():
        for v in views:
            out = renderer.render_visible(gmap.tensors(detach=True), INTR, v.w2c)
            np.testing.assert_allclose(out.color.numpy(), v.color, atol=2e-4)


def test_fit_is_identity_when_the_map_already_matches_and_without_views():
    gmap, renderer = two_walls(), Renderer()
    before = gmap.params["colors"].detach().clone()
    record = fit_map_colors(gmap, _views(gmap, renderer, np.ones(3), np.zeros(3)), INTR, renderer)
    np.testing.assert_allclose(record["gain"], 1.0, atol=1e-5)
    np.testing.assert_allclose(record["offset"], 0.0, atol=1e-5)
    gain, offset = ColorFit().solve()
    assert gain.tolist() == [1.0, 1.0, 1.0] and offset.tolist() == [0.0, 0.0, 0.0]
    torch.testing.assert_close(gmap.params["colors"].detach(), before, atol=1e-5, rtol=0)


def _run(fit: bool) -> tuple[Pipeline, dict]:
    config = load_config("cpu", overrides={"resolution": [80, 60], "checkpoint_every": 0, "eval_every": 2,
                                           "mapping": {"first_frame_iterations": 20, "final_color_fit": fit}})
    pipe = Pipeline(SyntheticSource(n_frames=6, width=80, height=60, seed=0), config)
    while pipe.step() is not None:
        pass
    return pipe, pipe.finish()


def test_a_run_with_the_fit_keeps_its_poses_and_reports_the_fit():
    plain, plain_metrics = _run(False)
    fitted, metrics = _run(True)
    assert "final_color_fit" not in plain_metrics
    record = metrics["final_color_fit"]
    assert record["keyframes"] == len(fitted.keyframes()) > 0
    for a, b in zip(plain.estimated_c2w(), fitted.estimated_c2w()):
        np.testing.assert_array_equal(a, b)
    # The map's colours are the plain run's under the reported gain and offset.
    expected = plain.engine.map_arrays()["colors"] * np.array(record["gain"]) + np.array(record["offset"])
    np.testing.assert_allclose(fitted.engine.map_arrays()["colors"], expected, atol=1e-5)
