"""mapping.final_hole_fill (final_holes.py, SplaTAM.finish): Gaussians where the frames kept for the
end-of-run passes have no depth and the finished map is empty, only they optimised; no pose moves,
no evaluated frame is read, a frame without such holes changes nothing, and a resumed run finishes
the same."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from splat_core.camera import Intrinsics, backproject, invert_pose
from splat_core.color_fit import FitSamples
from splat_core.config import load_config
from splat_core.final_holes import fill_final_holes
from splat_core.gaussians import PARAM_NAMES
from splat_core.metrics import is_evaluated
from splat_core.render import Renderer
from splat_core.run import Pipeline
from splat_core.synthetic import SyntheticSource
from tests.helpers.maps import oblique_camera, two_walls

INTR = Intrinsics(fx=60.0, fy=60.0, cx=40.0, cy=30.0, width=80, height=60)
BOX = (slice(26, 34), slice(25, 31))      # rows, columns of the hole: on the wall at z = 2 m


def _config(fraction: float = 0.05, passes: int = 3):
    return load_config("cpu", overrides={"mapping": {"final_hole_fill": fraction,
                                                     "final_hole_fill_iterations": passes}})


def _frame_and_map():
    """The two walls rendered at the identity pose (the frame's colour and depth), and the map with
    the wall's Gaussians behind BOX taken out: the frame sees the wall there (the caller takes its
    depth out)."""
    gmap, renderer = two_walls(), Renderer()
    w2c = np.eye(4)
    with torch.no_grad():
        out = renderer.render_visible(gmap.tensors(detach=True), INTR, w2c)
    alpha = out.alpha.numpy().reshape(60, 80)
    color = out.color.numpy().copy()
    # beside the walls the frame sees a far, black background the map does not have: valid depth
    depth = np.where(alpha > 0.5, out.depth.numpy().reshape(60, 80) / np.maximum(alpha, 1e-6), 3.0).astype(np.float32)
    means = gmap.means.detach().numpy()
    u = INTR.fx * means[:, 0] / means[:, 2] + INTR.cx
    v = INTR.fy * means[:, 1] / means[:, 2] + INTR.cy
    rows, cols = BOX
    behind = (u > cols.start - 2) & (u < cols.stop + 2) & (v > rows.start - 2) & (v < rows.stop + 2)
    gmap.prune(torch.as_tensor(~behind))
    return gmap, renderer, color, depth, w2c


def _box_error(gmap, renderer, color, w2c) -> float:
    with torch.no_grad():
        out = renderer.render_visible(gmap.tensors(detach=True), INTR, w2c)
    return float(np.abs(out.color.numpy() - color)[BOX].mean())


@pytest.mark.parametrize("passes", [0, 3])
def test_a_depth_hole_in_front_of_an_empty_map_is_filled_and_its_error_drops(passes):
    gmap, renderer, color, depth, w2c = _frame_and_map()
    before = _box_error(gmap, renderer, color, w2c)
    assert before > 0.2                                   # the wall's colour (0.8, 0.3, 0.2) renders black
    depth[BOX] = 0
    size = len(gmap)
    view = SimpleNamespace(frame_index=2, w2c=w2c, color=color, depth=depth)
    record = fill_final_holes(gmap, [view], INTR, renderer, _config(passes=passes))
    assert record["added"] > 0 and len(gmap) == size + record["added"] and record["frames"] == [2]
    assert record["steps"] == passes
    after = _box_error(gmap, renderer, color, w2c)
    assert after < 0.25 * before
    new = gmap.means.detach().numpy()[size:]
    np.testing.assert_allclose(new[:, 2], 2.0, atol=0.05)  # at the wall's depth beside the hole


def test_a_frame_without_empty_holes_leaves_the_map_bit_identical():
    gmap, renderer, color, depth, w2c = _frame_and_map()
    full = two_walls()
    before = {n: full.params[n].detach().clone() for n in PARAM_NAMES}
    with_depth = depth.copy()                              # valid everywhere
    covered = depth.copy()
    covered[30:36, 22:28] = 0                              # a hole where the map has the wall
    views = [SimpleNamespace(frame_index=k, w2c=w2c, color=color, depth=d) for k, d in ((2, with_depth), (7, covered))]
    record = fill_final_holes(full, views, INTR, renderer, _config())
    assert record["added"] == 0 and record["steps"] == 0
    for n in PARAM_NAMES:
        assert torch.equal(full.params[n].detach(), before[n])


def test_the_pass_never_reads_an_evaluated_frame():
    """Evaluated frames with a hole in front of the empty map, kept frames without: nothing is added;
    the other way round: the kept frames fill it."""
    for holes_on_evaluated in (True, False):
        gmap, renderer, color, depth, w2c = _frame_and_map()
        samples = FitSamples(INTR.scaled(160, 120), 5, keep_depth=True)     # kept at half size: INTR's
        big = lambda a: np.repeat(np.repeat(a, 2, axis=0), 2, axis=1)        # noqa: E731
        holed = depth.copy()
        holed[BOX] = 0
        for t in range(20):
            hole = is_evaluated(t, 5) == holes_on_evaluated
            samples.offer(t, big(color), big(holed if hole else depth))
        assert samples.frames == [2, 7, 12, 17] and sorted(samples.depths) == [2, 7, 12, 17]
        size = len(gmap)
        views = samples.views([w2c] * 20, lambda t: None)
        record = fill_final_holes(gmap, views, samples.intrinsics, renderer, _config())
        assert record["frames"] == [2, 7, 12, 17]
        assert (len(gmap) > size) == (not holes_on_evaluated)


def test_kept_depth_is_millimetres_at_half_size_and_survives_a_checkpoint():
    samples = FitSamples(INTR, 5, keep_depth=True)
    depth = np.full((60, 80), 1.2345, np.float32)
    depth[:10] = 0
    depth[10:20] = 70.0                                    # beyond uint16 millimetres: invalid
    samples.offer(2, np.zeros((60, 80, 3), np.float32), depth)
    kept = samples.depths[2]
    assert kept.dtype == np.uint16 and kept.shape == (30, 40)
    assert kept[0, 0] == 0 and kept[7, 0] == 0 and abs(int(kept[-1, -1]) - 1234) <= 1
    again = FitSamples(INTR, 5, keep_depth=True)
    again.load_arrays(samples.to_arrays(10))
    np.testing.assert_array_equal(again.depths[2], kept)
    assert "fit_depths" not in FitSamples(INTR, 5).to_arrays(10)


def _run_config(holes: float):
    # render metrics on frames 0, 1, 3, 5: the passes keep frames 2 and 4
    return load_config("cpu", overrides={"resolution": [80, 60], "checkpoint_every": 0, "eval_every": 2,
                                         "mapping": {"first_frame_iterations": 20, "final_hole_fill": holes,
                                                     "final_color_fit_min_improvement": 0.0}})


class ScreenSource(SyntheticSource):
    """The synthetic sequence with a "screen": no depth within 0.25 m of the surface point frame 0
    sees at its image centre, in every frame (a patch the depth camera misses)."""

    def __init__(self):
        super().__init__(n_frames=6, width=80, height=60, seed=0)
        self.centre = self._world(super().__getitem__(0))[30, 40]

    @staticmethod
    def _world(frame) -> np.ndarray:
        pts = backproject(frame.depth, frame.intrinsics)
        return pts @ frame.c2w_ref[:3, :3].T + frame.c2w_ref[:3, 3]

    def __getitem__(self, i: int):
        frame = super().__getitem__(i)
        screen = np.linalg.norm(self._world(frame) - self.centre, axis=-1) < 0.25
        return dataclasses.replace(frame, depth=np.where(screen, 0, frame.depth).astype(np.float32))


def _source():
    return ScreenSource()


def _run(holes: float, out=None) -> tuple[Pipeline, dict]:
    pipe = Pipeline(_source(), _run_config(holes), out)
    while pipe.step() is not None:
        pass
    return pipe, pipe.finish()


def test_a_run_with_the_hole_fill_keeps_its_poses_and_adds_gaussians():
    plain, plain_metrics = _run(0.0)
    filled, metrics = _run(0.1)
    assert "final_hole_fill" not in plain_metrics
    record = metrics["final_hole_fill"]
    assert record["frames"] == [2, 4] and record["added"] > 0
    for a, b in zip(plain.estimated_c2w(), filled.estimated_c2w()):
        np.testing.assert_array_equal(a, b)
    assert len(filled.engine.map_arrays()["means"]) == len(plain.engine.map_arrays()["means"]) + record["added"]


def _files(folder) -> dict:
    return {name: (folder / name).read_bytes() for name in ("map.ply", "trajectory.txt")}


def test_a_resumed_run_fills_the_same_holes(tmp_path):
    _, whole = _run(0.1, tmp_path / "whole")
    assert whole["final_hole_fill"]["added"] > 0
    first = Pipeline(_source(), _run_config(0.1), tmp_path / "part")
    for _ in range(3):
        first.step()
    assert "final_hole_fill" in first.finish()
    resumed = Pipeline(_source(), _run_config(0.1), tmp_path / "part", resume=True)
    while resumed.step() is not None:
        pass
    metrics = resumed.finish()
    assert metrics["final_hole_fill"]["added"] == whole["final_hole_fill"]["added"]
    assert _files(tmp_path / "part") == _files(tmp_path / "whole")
    # A finished run resumed: no frame left, the same passes again (not a second fill on top).
    again = Pipeline(_source(), _run_config(0.1), tmp_path / "part", resume=True)
    assert again.step() is None
    assert again.finish()["final_hole_fill"]["added"] == whole["final_hole_fill"]["added"]
    assert _files(tmp_path / "part") == _files(tmp_path / "whole")


def test_the_optimised_crop_renders_what_the_whole_image_renders_there():
    """optimise_new renders only the part of a frame the new Gaussians reach: the same pixels."""
    from splat_core.final_holes import _crop

    gmap, renderer = two_walls(), Renderer()
    w2c = invert_pose(oblique_camera())
    panel = gmap.tensors(detach=True).select(gmap.means.detach()[:, 0] > 0.3)
    crop = _crop(panel, INTR, w2c, renderer, margin=2)
    assert crop is not None and crop.width < INTR.width
    top, left = int(round(INTR.cy - crop.cy)), int(round(INTR.cx - crop.cx))
    with torch.no_grad():
        whole = renderer.render(gmap.tensors(detach=True), INTR, w2c).color.numpy()
        part = renderer.render(gmap.tensors(detach=True), crop, w2c).color.numpy()
    np.testing.assert_allclose(part, whole[top:top + crop.height, left:left + crop.width], atol=1e-5)
