"""mapping.final_color_fit (color_fit.py, SplaTAM.finish): one gain and offset per channel, least
squares over frames kept for it (never an evaluated frame), applied to the map's colours; the run's
poses untouched; the fitted map published and checkpointed, and a resumed run fits the same."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from splat_core.camera import Intrinsics, invert_pose
from splat_core.color_fit import FIT_FRAMES_MAX, ColorFit, FitSamples, fit_map_colors, is_fit_frame
from splat_core.metrics import is_evaluated
from splat_core.config import load_config
from splat_core.render import Renderer
from splat_core.run import Pipeline
from splat_core.synthetic import SyntheticSource
from tests.helpers.maps import oblique_camera, two_walls

INTR = Intrinsics(fx=60.0, fy=60.0, cx=40.0, cy=30.0, width=80, height=60)


def _views(gmap, renderer, gain, offset, frames=(2, 6)):
    """Keyframe-like views whose colours are the map's render under a known gain and offset."""
    views = []
    for c2w, k in zip((np.eye(4), oblique_camera()), frames):
        w2c = invert_pose(c2w)
        with torch.no_grad():
            out = renderer.render_visible(gmap.tensors(detach=True), INTR, w2c)
        color = out.color.numpy() * gain + offset * out.alpha.numpy().reshape(60, 80, 1)
        views.append(SimpleNamespace(color=color, w2c=w2c, frame_index=k))
    return views


def test_the_solve_is_the_least_squares_solution_of_each_channel():
    rng = np.random.default_rng(3)
    fit, rows = ColorFit(), []
    for _ in range(3):
        r, a = rng.uniform(0, 1, (20, 30, 3)), rng.uniform(0, 1, (20, 30))
        o = 0.7 * r + 0.1 * a[..., None] + rng.normal(0, 0.05, r.shape)      # noisy: no exact fit
        fit.add(torch.as_tensor(r), torch.as_tensor(a), torch.as_tensor(o))
        rows.append((r.reshape(-1, 3), a.reshape(-1), o.reshape(-1, 3)))
    gain, offset = fit.solve()
    r, a, o = (np.concatenate(x) for x in zip(*rows))
    for c in range(3):
        (g, b), *_ = np.linalg.lstsq(np.c_[r[:, c], a], o[:, c], rcond=None)
        assert gain[c] == pytest.approx(g, rel=1e-9) and offset[c] == pytest.approx(b, abs=1e-9)


def test_fit_recovers_a_known_gain_and_offset_and_the_renders_then_match():
    gmap, renderer = two_walls(), Renderer()
    gain, offset = np.array([1.3, 0.9, 1.1]), np.array([0.05, -0.02, 0.0])
    views = _views(gmap, renderer, gain, offset)
    record = fit_map_colors(gmap, views, INTR, renderer)
    assert record["views"] == 2
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


def _noisy_views(gmap, renderer, gain, seed=0, frames=(2, 7, 12, 17)):
    """Views around the two walls whose colours are the map's render x gain plus pixel noise (sd 0.05)."""
    rng = np.random.default_rng(seed)
    views = []
    for i, k in enumerate(frames):
        c2w = oblique_camera() if i % 2 else np.eye(4)
        c2w = c2w.copy()
        c2w[:3, 3] += 0.02 * i
        w2c = invert_pose(c2w)
        with torch.no_grad():
            out = renderer.render_visible(gmap.tensors(detach=True), INTR, w2c)
        color = out.color.numpy() * gain + rng.normal(0, 0.05, out.color.shape)
        views.append(SimpleNamespace(color=color, w2c=w2c, frame_index=k))
    return views


def test_the_held_out_ratio_scores_each_half_s_fit_on_the_other_half():
    rng = np.random.default_rng(5)
    fit, rows = ColorFit(), []
    for k in range(5):
        r, a = rng.uniform(0, 1, (10, 12, 3)), rng.uniform(0.5, 1, (10, 12))
        o = (0.8 + 0.05 * k) * r + 0.05 * a[..., None] + rng.normal(0, 0.05, r.shape)
        fit.add(torch.as_tensor(r), torch.as_tensor(a), torch.as_tensor(o))
        rows.append((r.reshape(-1, 3), a.reshape(-1), o.reshape(-1, 3)))
    fitted = identity = 0.0
    for train, test in (((0, 2, 4), (1, 3)), ((1, 3), (0, 2, 4))):
        r, a, o = (np.concatenate(x) for x in zip(*[rows[i] for i in train]))
        rt, at, ot = (np.concatenate(x) for x in zip(*[rows[i] for i in test]))
        for c in range(3):
            (g, b), *_ = np.linalg.lstsq(np.c_[r[:, c], a], o[:, c], rcond=None)
            fitted += float(((g * rt[:, c] + b * at - ot[:, c]) ** 2).sum())
            identity += float(((rt[:, c] - ot[:, c]) ** 2).sum())
    assert fit.held_out_ratio() == pytest.approx(fitted / identity, rel=1e-9)
    # The prior pulls the fit towards identity: a weight per pixel far above the data's leaves it there.
    gain, offset = fit.solve(prior=1e6)
    np.testing.assert_allclose(gain, 1.0, atol=1e-4)
    np.testing.assert_allclose(offset, 0.0, atol=1e-4)
    light = fit.solve(prior=0.03)[0]
    assert np.all(np.abs(light - 1.0) < np.abs(fit.solve()[0] - 1.0))
    assert ColorFit().held_out_ratio() == 1.0


def test_a_map_of_the_right_colours_is_left_as_it_is_and_a_wrongly_exposed_one_is_corrected():
    renderer = Renderer()
    right = two_walls()
    before = right.params["colors"].detach().clone()
    record = fit_map_colors(right, _noisy_views(right, renderer, 1.0), INTR, renderer, min_improvement=0.05)
    # The fit of noise alone is near identity, and held out it does not beat the map: not applied.
    np.testing.assert_allclose(record["fitted_gain"], 1.0, atol=0.05)
    assert not record["kept"] and record["held_out_ratio"] > 0.95
    assert record["gain"] == [1.0, 1.0, 1.0] and record["offset"] == [0.0, 0.0, 0.0]
    assert torch.equal(right.params["colors"].detach(), before)
    # A slight, consistent mismatch (1 %) does not pass the test either.
    slight = two_walls()
    assert not fit_map_colors(slight, _noisy_views(slight, renderer, 0.99), INTR, renderer, 0.05)["kept"]
    # Frames 30 % brighter than the map: corrected.
    dark = two_walls()
    record = fit_map_colors(dark, _noisy_views(dark, renderer, 1.3), INTR, renderer, min_improvement=0.05)
    assert record["kept"] and record["held_out_ratio"] < 0.5
    np.testing.assert_allclose(record["gain"], 1.3, atol=0.03)
    np.testing.assert_allclose(record["offset"], 0.0, atol=0.02)
    torch.testing.assert_close(dark.params["colors"].detach(), before * torch.tensor(record["gain"], dtype=before.dtype)
                               + torch.tensor(record["offset"], dtype=before.dtype))


def test_the_cpu_preset_fits_and_keeps_the_fit_only_past_the_held_out_test():
    mc = load_config("cpu").mapping
    assert mc.final_color_fit and mc.final_color_fit_min_improvement > 0 and mc.final_color_fit_prior > 0
    assert load_config("live").mapping.final_color_fit


def test_the_kept_frames_are_never_evaluated_and_stay_bounded():
    for every in (1, 2, 3, 5, 10):
        kept = [t for t in range(200) if is_fit_frame(t, every)]
        assert not any(is_evaluated(t, every) for t in kept)
        assert len(kept) >= (200 // every - 1 if every > 1 else 0)      # one between every two evaluated
    samples = FitSamples(INTR, 5)
    for t in range(2000):
        samples.offer(t, np.full((60, 80, 3), (t % 256) / 255.0, np.float32))
        assert len(samples) <= FIT_FRAMES_MAX
    frames = samples.frames
    assert len(frames) > FIT_FRAMES_MAX // 2 and frames[0] < 100 and frames[-1] > 1800     # spread over the run
    assert not any(is_evaluated(t, 5) for t in frames)
    assert all(c.shape == (30, 40, 3) and c[0, 0, 0] == t % 256 for t, c in samples.kept)


def test_an_evaluated_frame_never_enters_the_fit():
    """Frames whose colour contradicts the map everywhere but on the evaluated ones: the fit sees only
    the kept frames."""
    gmap, renderer = two_walls(), Renderer()
    samples = FitSamples(INTR.scaled(160, 120), 5)       # kept at half size: INTR's 80 x 60
    w2c = invert_pose(oblique_camera())
    with torch.no_grad():
        render = renderer.render_visible(gmap.tensors(detach=True), INTR, w2c).color.numpy()
    big = np.repeat(np.repeat(render, 2, axis=0), 2, axis=1)
    for t in range(20):
        # evaluated frames: 3x too dark; the kept ones (2, 7, 12, 17): the map's colour x 0.9
        samples.offer(t, big * (0.3 if is_evaluated(t, 5) else 0.9))
    assert samples.frames == [2, 7, 12, 17]
    record = fit_map_colors(gmap, samples.views([w2c] * 20, lambda t: None), samples.intrinsics, renderer)
    np.testing.assert_allclose(record["gain"], 0.9, atol=0.01)
    assert record["frames"] == [2, 7, 12, 17]


def _config(fit: bool = True):
    # render metrics on frames 0, 1, 3, 5: the fit keeps frames 2 and 4; least squares, applied
    # without the held-out test (two frames of a synthetic scene would not pass it)
    return load_config("cpu", overrides={"resolution": [80, 60], "checkpoint_every": 0, "eval_every": 2,
                                         "mapping": {"first_frame_iterations": 20, "final_color_fit": fit,
                                                     "final_color_fit_min_improvement": 0.0,
                                                     "final_color_fit_prior": 0.0}})


def _source():
    return SyntheticSource(n_frames=6, width=80, height=60, seed=0)


def _run(fit: bool, out=None, engine="sequential") -> tuple[Pipeline, dict]:
    pipe = Pipeline(_source(), _config(fit), out, engine=engine)
    while pipe.step() is not None:
        pass
    return pipe, pipe.finish()


def test_a_run_with_the_fit_keeps_its_poses_and_reports_the_fit():
    plain, plain_metrics = _run(False)
    fitted, metrics = _run(True)
    assert "final_color_fit" not in plain_metrics
    record = metrics["final_color_fit"]
    assert record["frames"] == [2, 4] and record["views"] == 2
    assert not set(record["frames"]) & set(metrics["eval_frames"])
    for a, b in zip(plain.estimated_c2w(), fitted.estimated_c2w()):
        np.testing.assert_array_equal(a, b)
    # The map's colours are the plain run's under the reported gain and offset.
    expected = plain.engine.map_arrays()["colors"] * np.array(record["gain"]) + np.array(record["offset"])
    np.testing.assert_allclose(fitted.engine.map_arrays()["colors"], expected, atol=1e-5)


@pytest.mark.parametrize("engine", ["sequential", "live"])
def test_the_published_map_is_the_fitted_one(engine):
    """What the viewer shows at the end (pipe.map_version()) is the map finish() fitted."""
    pipe = Pipeline(_source(), _config(), engine=engine)
    while pipe.step() is not None:
        pass
    pipe.engine.drain()
    before = pipe.map_version()
    record = pipe.finish()["final_color_fit"]
    after = pipe.map_version()
    assert after.number > before.number
    np.testing.assert_array_equal(after.arrays["colors"], pipe.engine.map_arrays()["colors"])
    expected = before.arrays["colors"] * np.array(record["gain"]) + np.array(record["offset"])
    np.testing.assert_allclose(after.arrays["colors"], expected, atol=1e-5)
    assert np.abs(after.arrays["colors"] - before.arrays["colors"]).max() > 1e-3


def _files(folder) -> dict:
    return {name: (folder / name).read_bytes() for name in ("map.ply", "trajectory.txt")}


def test_a_resumed_run_fits_the_same_map(tmp_path):
    _, whole = _run(True, tmp_path / "whole")
    # Stopped after 3 frames: finished there (fitted and checkpointed), then resumed to the end.
    first = Pipeline(_source(), _config(), tmp_path / "part")
    for _ in range(3):
        first.step()
    assert "final_color_fit" in first.finish()
    resumed = Pipeline(_source(), _config(), tmp_path / "part", resume=True)
    while resumed.step() is not None:
        pass
    metrics = resumed.finish()
    assert metrics["final_color_fit"]["gain"] == whole["final_color_fit"]["gain"]
    assert _files(tmp_path / "part") == _files(tmp_path / "whole")
    # A finished run resumed: no frame left, the same fit again (not a second one on top of the first).
    again = Pipeline(_source(), _config(), tmp_path / "part", resume=True)
    assert again.step() is None
    assert again.finish()["final_color_fit"]["gain"] == whole["final_color_fit"]["gain"]
    assert _files(tmp_path / "part") == _files(tmp_path / "whole")
    # The checkpoint's map (browsing, refinement, renders read it) is the fitted one.
    state = np.load(tmp_path / "part" / "checkpoint" / "state.npz")
    np.testing.assert_array_equal(state["map_colors"], resumed.engine.map_arrays()["colors"])
