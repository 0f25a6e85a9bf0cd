"""mapping.final_refine (final_refine.py, SplaTAM.finish): the whole map optimised over every
keyframe after the last frame, kept only where held-out frames render closer, else put back bit
for bit; no pose moves; a resumed run refines the same."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from splat_core.camera import Intrinsics, invert_pose
from splat_core.config import load_config
from splat_core.final_refine import held_out_error, keyframe_order, refine_final_map
from splat_core.mapping import View
from splat_core.render import Renderer
from splat_core.run import Pipeline
from splat_core.synthetic import SyntheticSource, look_at_c2w
from tests.helpers.maps import oblique_camera, two_walls

INTR = Intrinsics(fx=60.0, fy=60.0, cx=40.0, cy=30.0, width=80, height=60)
POSES = [np.eye(4), oblique_camera(), look_at_c2w(np.array([-0.2, 0.2, -0.3]), np.array([0.0, 0.0, 1.8]))]


def _config(passes: float = 20.0):
    return load_config("cpu", overrides={"mapping": {"final_refine": passes}})


def _observed(gmap, renderer, c2w):
    """The map rendered at c2w: an exact frame (colour, depth) of it."""
    w2c = invert_pose(c2w)
    with torch.no_grad():
        out = renderer.render_visible(gmap.tensors(detach=True), INTR, w2c)
    alpha = out.alpha.reshape(60, 80)
    depth = torch.where(alpha > 0.5, out.depth.reshape(60, 80) / alpha.clamp(min=1e-6), torch.zeros(()))
    return out.color.clone(), depth, w2c


def _scene():
    """The two walls' frames (keyframes at the first two poses, a held-out frame at the third), and
    the same map with its colours off by a known amount: what the refinement should undo."""
    truth, renderer = two_walls(), Renderer()
    frames = [_observed(truth, renderer, c2w) for c2w in POSES]
    keyframes = [View(color, depth, w2c) for color, depth, w2c in frames[:2]]
    color, _, w2c = frames[2]
    held_out = [SimpleNamespace(color=color.numpy(), w2c=w2c, frame_index=7)]
    gmap = two_walls()
    with torch.no_grad():
        gmap.params["colors"].add_(torch.tensor([0.15, -0.1, 0.1]))
    return gmap, renderer, keyframes, held_out


def test_a_refinement_held_out_frames_bear_out_is_kept_and_lowers_their_error():
    gmap, renderer, keyframes, held_out = _scene()
    before = held_out_error(gmap, held_out, INTR, renderer)
    record = refine_final_map(gmap, keyframes, lambda view: view, INTR, held_out, INTR, renderer, _config())
    after = held_out_error(gmap, held_out, INTR, renderer)
    assert record["kept"] and record["steps"] == 40 and record["keyframes"] == 2
    assert after < 0.25 * before
    assert record["held_out_psnr_after"] > record["held_out_psnr_before"] + 6


def test_a_refinement_held_out_frames_do_not_bear_out_is_put_back_bit_for_bit():
    gmap, renderer, keyframes, held_out = _scene()
    # The held-out frame is the map as it is (colours off): fitting the keyframes moves away from it.
    _, _, w2c = _observed(gmap, renderer, POSES[2])
    held_out = [SimpleNamespace(color=_observed(gmap, renderer, POSES[2])[0].numpy(), w2c=w2c, frame_index=7)]
    before = gmap.to_numpy()
    record = refine_final_map(gmap, keyframes, lambda view: view, INTR, held_out, INTR, renderer, _config())
    assert not record["kept"] and record["held_out_psnr_after"] < record["held_out_psnr_before"]
    for name, array in gmap.to_numpy().items():
        np.testing.assert_array_equal(array, before[name])


def test_each_pass_visits_every_keyframe_once_in_an_order_drawn_from_the_seed():
    orders = {seed: [[keyframe_order(7, k, seed) for k in range(7 * p, 7 * p + 7)] for p in range(3)]
              for seed in (0, 1)}
    assert all(sorted(order) == list(range(7)) for passes in orders.values() for order in passes)
    assert orders[0][0] != orders[0][1] and orders[0][0] != orders[1][0]


def _run(passes: float, out=None, engine: str = "sequential", frames: int = 8):
    config = load_config("cpu", overrides={"resolution": [80, 60], "checkpoint_every": 0, "eval_every": 2,
                                           "mapping": {"first_frame_iterations": 20, "final_refine": passes}})
    pipe = Pipeline(SyntheticSource(n_frames=frames, width=80, height=60, seed=0), config, out, engine=engine)
    while pipe.step() is not None:
        pass
    return pipe, pipe.finish()


@pytest.mark.parametrize("engine", ["sequential", "live"])
def test_a_run_with_the_refinement_keeps_its_poses_and_reports_it(engine):
    plain, plain_metrics = _run(0.0, engine=engine)
    refined, metrics = _run(2.0, engine=engine)
    assert "final_refine" not in plain_metrics
    record = metrics["final_refine"]
    assert record["keyframes"] == len(refined.engine.keyframes()) and record["steps"] == 2 * record["keyframes"]
    assert record["held_out_frames"] > 0
    for a, b in zip(plain.estimated_c2w(), refined.estimated_c2w()):
        np.testing.assert_array_equal(a, b)
    if record["kept"]:
        assert np.abs(plain.engine.map_arrays()["means"] - refined.engine.map_arrays()["means"]).max() > 0


def test_a_resumed_run_refines_the_same_map(tmp_path):
    _, whole = _run(2.0, tmp_path / "whole")
    config = load_config("cpu", overrides={"resolution": [80, 60], "checkpoint_every": 0, "eval_every": 2,
                                           "mapping": {"first_frame_iterations": 20, "final_refine": 2.0}})
    source = lambda: SyntheticSource(n_frames=8, width=80, height=60, seed=0)  # noqa: E731
    first = Pipeline(source(), config, tmp_path / "part")
    for _ in range(5):
        first.step()
    assert "final_refine" in first.finish()       # finished (refined and checkpointed) after 5 frames
    resumed = Pipeline(source(), config, tmp_path / "part", resume=True)
    while resumed.step() is not None:
        pass
    metrics = resumed.finish()
    assert metrics["final_refine"] == {**whole["final_refine"], "seconds": metrics["final_refine"]["seconds"]}
    for name in ("map.ply", "trajectory.txt"):
        assert (tmp_path / "part" / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()
