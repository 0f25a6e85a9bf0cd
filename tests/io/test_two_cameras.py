"""Two cameras (docs/formats.md): camera files that describe the colour camera, registration of
colour to depth at load, and the colour camera estimated from a capture's own edges."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from helpers import captures as cf
from helpers.two_cameras import COLOR_FOCAL_RATIO, DEPTH_TO_COLOR, write_two_camera_tum
from splat_core.errors import InputError
from splat_core.io import open_capture
from splat_core.registration import project_depth
from splat_core.registration_estimate import edge_mask, estimate_registration


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    return write_two_camera_tum(tmp_path_factory.mktemp("two") / "cap", n=6)


@pytest.fixture(scope="module")
def raw(tmp_path_factory):
    """The same capture with a camera file that only says colour and depth are not registered."""
    return write_two_camera_tum(tmp_path_factory.mktemp("raw") / "cap", n=6, describe=False)


def test_camera_file_describes_two_cameras(two):
    src = open_capture(two.path)
    assert src.registered and src.two_cameras is not None
    assert src.two_cameras.color.fx == pytest.approx(two.color_intr.fx)
    np.testing.assert_allclose(src.two_cameras.translation, DEPTH_TO_COLOR)
    np.testing.assert_allclose(src.two_cameras.rotation, np.eye(3))
    assert src.intrinsics == two.depth_intr   # the frames are the depth camera's
    f = src[0]
    assert f.color.shape[:2] == f.depth.shape == (two.depth_intr.height, two.depth_intr.width)


@pytest.mark.parametrize("extra, message", [
    ("color_intrinsics: {fx: 500, fy: 500, cx: 160}\n", "color_intrinsics' is missing cy, width, height"),
    ("color_intrinsics: {fx: 500, fy: 500, cx: 160, cy: 120, width: 320, height: 240}\n"
     "depth_to_color: {translation: [0.02, 0]}\n", "translation' must be a list of 3 numbers"),
    ("color_intrinsics: {fx: 500, fy: 500, cx: 160, cy: 120, width: 320, height: 240}\n"
     "depth_to_color: {translation: [25, 0, 0]}\n", "millimetres written as metres"),
    ("color_intrinsics: {fx: 500, fy: 500, cx: 160, cy: 120, width: 320, height: 240}\n"
     "depth_to_color: {rotation_xyzw: [0, 0, 0, 2]}\n", "unit quaternion"),
    ("depth_to_color: {translation: [0.02, 0, 0]}\n", "depth_to_color is given without it"),
    ("depth_registered_to_rgb: true\n"
     "color_intrinsics: {fx: 500, fy: 500, cx: 160, cy: 120, width: 320, height: 240}\n", "contradicts"),
])
def test_bad_two_camera_description_is_one_clear_error(tmp_path, extra, message):
    fx = cf.write_tum(tmp_path / "t", n=2)
    cam = fx.path / "camera.yaml"
    cam.write_text(cam.read_text() + extra)
    with pytest.raises(InputError, match="camera.yaml.*" + message.replace("(", r"\(")):
        open_capture(fx.path)


def test_registered_capture_is_left_unchanged_bitwise(tmp_path):
    fx = cf.write_tum(tmp_path / "t", n=3)
    before = [open_capture(fx.path)[i] for i in range(3)]
    raw_color = open_capture(fx.path).raw_pair(1)[0]
    k = fx.seq.color_intr
    cam = fx.path / "camera.yaml"
    cam.write_text(cam.read_text() + f"color_intrinsics: {{fx: {k.fx!r}, fy: {k.fy!r}, cx: {k.cx!r}, cy: {k.cy!r}, "
                   f"width: {k.width}, height: {k.height}}}\ndepth_to_color: {{translation: [0, 0, 0]}}\n")
    src = open_capture(fx.path)
    assert src.two_cameras is None and src.registered   # one camera described twice
    for i in range(3):
        assert np.array_equal(src[i].color, before[i].color) and np.array_equal(src[i].depth, before[i].depth)
    assert np.array_equal(before[1].color, raw_color)


def test_registration_reproduces_the_single_camera_colour(two):
    src = open_capture(two.path)
    for k, i in enumerate(two.frames[:3]):
        exact, depth = two.source.scene.render(two.source.c2w[i], two.depth_intr)
        f = src[k]
        near_edge = cv2.dilate(edge_mask(depth).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
        kept = f.depth > 0
        assert kept.mean() > 0.97
        err = np.abs(f.color - exact).mean(axis=2)[kept & ~near_edge]
        assert err.mean() < 0.006 and np.quantile(err, 0.99) < 0.06
        # without registration the same pixels are far off
        assert np.abs(src.raw_pair(k)[0] - exact).mean(axis=2)[kept & ~near_edge].mean() > 5 * err.mean()


def test_zbuffer_hides_points_the_colour_camera_does_not_see(two):
    src = open_capture(two.path)
    hidden_kept = hidden_total = visible_dropped = visible_total = 0
    for k, i in enumerate(two.frames):
        _, depth = two.source.scene.render(two.source.c2w[i], two.depth_intr)
        _, color_depth = two.source.scene.render(two.color_c2w(i), two.color_intr)
        u, v, z = project_depth(depth, two.depth_intr, src.two_cameras, two.color_intr)
        inside = (u >= 0) & (v >= 0) & (u <= two.color_intr.width - 1) & (v <= two.color_intr.height - 1)
        seen_z = np.where(inside, color_depth[np.clip(np.rint(v), 0, 239).astype(int),
                                              np.clip(np.rint(u), 0, 319).astype(int)], 0)
        hidden = inside & (z > seen_z + 0.1)      # the colour camera sees something 10 cm nearer there
        visible = inside & (np.abs(z - seen_z) < 0.01)
        kept = src[k].depth > 0
        hidden_kept += int((hidden & kept).sum())
        hidden_total += int(hidden.sum())
        visible_dropped += int((visible & ~kept).sum())
        visible_total += int(visible.sum())
    assert hidden_total > 100                       # the capture has occlusions to test
    assert hidden_kept < 0.05 * hidden_total
    assert visible_dropped < 0.01 * visible_total   # (0.6 %: those within a pixel of a nearer silhouette)


def test_estimation_recovers_the_colour_camera(raw):
    src = open_capture(raw.path)
    assert not src.registered and src.two_cameras is None
    e = estimate_registration(src, n_frames=6)
    assert e.focal_ratio == pytest.approx(COLOR_FOCAL_RATIO, rel=0.01)
    assert np.linalg.norm(np.array(e.translation) - DEPTH_TO_COLOR) < 0.003
    assert not e.registered and e.after > 1.5 * e.before
    assert e.cameras.color.fx == pytest.approx(raw.color_intr.fx, rel=0.01)


def test_estimation_says_a_registered_capture_is_registered(tmp_path):
    cap = write_two_camera_tum(tmp_path / "one", n=4, ratio=1.0, translation=[0.0, 0.0, 0.0], describe=False)
    e = estimate_registration(open_capture(cap.path), n_frames=4)
    assert e.registered and e.shift_px < 1.0


def test_info_reports_edge_agreement_and_the_lines_to_add(raw, two):
    from app.commands.info import gather, format_text

    info = gather(open_capture(raw.path), estimate=True)
    text = format_text(info)
    assert "not registered (camera file)" in text and "color_intrinsics: {fx:" in text and "depth_to_color:" in text
    after = gather(open_capture(two.path))["registration"]
    assert after["two_cameras"] and after["edge_agreement"] > 1.5 * info["registration"]["edge_agreement"]


DATA = __import__("pathlib").Path(__file__).resolve().parents[2].parent / "shared" / "data"


@pytest.mark.skipif(not (DATA / "7scenes_redkitchen_300").is_dir(), reason="shared data absent")
def test_estimation_on_real_captures():
    e = estimate_registration(open_capture(DATA / "7scenes_redkitchen_300"))
    assert e.cameras.color.fx == pytest.approx(525, rel=0.02) and not e.registered
    assert e.translation[0] == pytest.approx(-0.0254, abs=0.004)   # literature's Kinect v1 offset
    assert estimate_registration(open_capture(DATA / "sun3d_3dmatch_fragment1")).registered


def test_a_raw_capture_is_registered_from_its_own_estimate(raw):
    # The camera file says colour and depth are not registered and names no colour camera (as
    # 7-Scenes'): the pipeline estimates the colour camera, registers every frame and tracks with
    # colour; with estimate_registration off it keeps the old rule (depth alone).
    from splat_core.config import load_config
    from splat_core.run import Pipeline

    pipe = Pipeline(open_capture(raw.path), load_config("cpu"), max_frames=2)
    assert pipe.source.registered and pipe.source.two_cameras is not None
    assert pipe.source.two_cameras.color.fx == pytest.approx(raw.color_intr.fx, rel=0.01)
    assert "estimated from the capture" in pipe.notes[0] and pipe.config.tracking.color_weight > 0
    frame = pipe.source[0]
    registered = frame.color[frame.depth > 0]
    exact = raw.source[raw.frames[0]].color[frame.depth > 0]
    assert np.median(np.abs(registered - exact)) < 0.02        # colour from the right pixel again
    from splat_core.io.playback import RealtimePlayback

    played = Pipeline(RealtimePlayback(open_capture(raw.path), fps=30), load_config("cpu"), engine="live")
    assert played.source.registered and played.source.inner.two_cameras is not None    # --realtime too
    off = Pipeline(open_capture(raw.path), load_config("cpu", {"estimate_registration": False}), max_frames=2)
    assert not off.source.registered and off.config.tracking.color_weight == 0
    assert "tracking uses depth alone" in off.notes[0]


def test_a_capture_registered_by_its_writer_is_not_estimated(tmp_path, raw):
    """A camera file that says depth is registered is believed (the search would take motion between
    the colour and depth exposures for an offset, docs/formats.md): `info` says why it does not
    estimate. The same frames whose camera file says they are not registered are estimated."""
    from app.commands.info import format_text, gather

    cap = write_two_camera_tum(tmp_path / "said", n=3, describe=False)
    cam = cap.path / "camera.yaml"
    cam.write_text(cam.read_text().replace("depth_registered_to_rgb: false", "depth_registered_to_rgb: true"))
    src = open_capture(cap.path)
    assert src.registered and src.registered_by == "camera.yaml says depth_registered_to_rgb: true"
    info = gather(src, estimate=True)
    assert info["registration"]["estimate"] == {"already_registered": True, "not_estimated": src.registered_by}
    text = format_text(info)
    assert "registered (camera.yaml says depth_registered_to_rgb: true)" in text and "not estimated" in text
    assert "color_intrinsics" not in text
    said_not = gather(open_capture(raw.path), estimate=True)["registration"]
    assert said_not["registered_by"] is None and not said_not["estimate"]["already_registered"]


def test_which_readers_say_their_writer_registered_the_frames(tmp_path):
    from splat_core.synthetic import SyntheticSource

    assert "ScanNet" in open_capture(cf.write_scannet(tmp_path / "sn", n=2, color_size=(64, 48)).path).registered_by
    assert "ARKit" in open_capture(cf.write_record3d(tmp_path / "r.r3d", n=2).path).registered_by
    assert "one camera" in SyntheticSource(n_frames=2, width=32, height=24).registered_by
    plain = open_capture(cf.write_tum(tmp_path / "t", n=2).path)   # a camera file that does not say
    assert plain.registered and plain.registered_by is None


@pytest.mark.skipif(not (DATA / "tum_fr1_xyz_pair").is_dir(), reason="shared data absent")
def test_tum_is_reported_registered_without_an_estimate():
    from app.commands.info import gather

    reg = gather(open_capture(DATA / "tum_fr1_xyz_pair"), estimate=True)["registration"]
    assert reg["estimate"]["already_registered"] and "depth_registered_to_rgb: true" in reg["registered_by"]
