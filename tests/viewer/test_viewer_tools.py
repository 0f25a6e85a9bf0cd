"""The viewer's tools without a browser: measuring (picking points from our depth render),
the export panel beside live SLAM, and the camera-path video panel."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from app.viewer.measure import MeasureTool, pick_point
from app.worker import SlamWorker
from splat_core.camera import Intrinsics
from splat_core.render import Renderer
from splat_core.synthetic import look_at_c2w

from helpers.viewer import FakePipeline, wait_until
from helpers.maps import A, B, oblique_camera, ray_to, snapshot_of, two_walls












INTR = Intrinsics.from_fov(np.deg2rad(60.0), 320, 240)


def test_picked_points_give_a_known_distance_within_a_centimetre():
    g = two_walls().tensors(detach=True)
    renderer = Renderer(0.01, "cpu")
    for c2w in (np.eye(4), oblique_camera()):
        a = pick_point(g, c2w, INTR, ray_to(c2w, A), renderer=renderer)
        b = pick_point(g, c2w, INTR, ray_to(c2w, B), renderer=renderer)
        assert a is not None and b is not None
        assert np.linalg.norm(a - A) < 0.01 and np.linalg.norm(b - B) < 0.01, (a, b)
        assert abs(np.linalg.norm(a - b) - np.linalg.norm(A - B)) < 0.01
    # rays that miss the map, or point behind the camera, give no point
    assert pick_point(g, np.eye(4), INTR, ray_to(np.eye(4), np.array([0.0, 0.35, 2.0])), renderer=renderer) is None
    assert pick_point(g, np.eye(4), INTR, np.array([0.0, 0.0, -1.0]), renderer=renderer) is None




def test_measure_tool_two_clicks_then_a_new_measurement(server):
    snap = snapshot_of(two_walls())
    tool = MeasureTool(server, lambda: snap, render_backend="cpu")
    c2w = oblique_camera()
    assert tool.click(c2w, INTR, ray_to(c2w, A)) is not None
    assert tool.distance is None and "second point" in tool.info.content
    assert tool.click(c2w, INTR, ray_to(c2w, np.array([-0.3, 0.55, 2.0]))) is None   # a miss changes nothing
    assert len(tool.points) == 1
    tool.click(c2w, INTR, ray_to(c2w, B))
    assert abs(tool.distance - np.linalg.norm(A - B)) < 0.01
    assert f"{tool.distance:.3f} m" in tool.info.content
    label = server.scene.get_handle_by_name("/measure/label")
    assert label is not None and server.scene.get_handle_by_name("/measure/line") is not None
    tool.click(c2w, INTR, ray_to(c2w, B))            # a third click starts over
    assert len(tool.points) == 1 and tool.distance is None
    assert server.scene.get_handle_by_name("/measure/line") is None
    tool.enabled.value = True                        # listening to scene clicks, once
    tool.enabled.value = True
    assert sum(e.callback == tool._on_click for e in server.scene._scene_pointer_cb) == 1
    tool.enabled.value = False
    assert not server.scene._scene_pointer_cb


def test_export_panel_exports_every_format_while_slam_runs(server, tmp_path):
    from app.exports import FORMATS
    from app.viewer import build_viewer
    from splat_core.io.map_files import read_map_file

    pipe = FakePipeline(total=100_000, per_frame=5, frame_seconds=0.02)   # runs until stopped
    worker = SlamWorker(pipe, live_render=False)
    app = build_viewer(server, worker, export_dir=tmp_path, render_backend="cpu", update_hz=20, running_update_hz=20)
    try:
        worker.start()
        assert worker.wait_for(lambda s: s.num_gaussians >= 100, 60)
        before = worker.latest().processed
        for fmt in FORMATS:
            path = app.export_panel.export(fmt)
            assert path.parent == tmp_path / "exports" and path.is_file()
            if fmt == "html":
                assert b"<html" in path.read_bytes()[:2000].lower()
            else:
                n = len(read_map_file(path)["means"])
                assert n >= 100 and n % 5 == 0       # one snapshot's map: whole frames of 5
            assert fmt in app.export_panel.info.content or path.name in app.export_panel.info.content
        assert worker.wait_for(lambda s: s.processed > before + 5, 60)   # SLAM went on
        assert worker.latest().state == "running"
        assert app.export_panel.exports == len(FORMATS)
        assert not (tmp_path / "map.ply").exists()   # never over the run folder's own map
    finally:
        worker.stop(join_timeout=10)
        app.close()


@pytest.fixture
def video_panel(server, tmp_path):
    pytest.importorskip("imageio_ffmpeg", reason="imageio-ffmpeg not installed (pip install '.[video]')")
    from app.viewer.video_panel import CameraPathPanel

    snap = snapshot_of(two_walls())
    return CameraPathPanel(server, lambda: snap, export_dir=tmp_path, render_backend="cpu")


def test_video_panel_renders_the_path_it_draws(video_panel, server, tmp_path):
    from app.video import read_mp4

    panel = video_panel
    with pytest.raises(Exception, match="two keyframes"):
        panel.render_video()
    panel.add_view(np.eye(4), np.deg2rad(60.0))
    panel.add_view(oblique_camera(), np.deg2rad(60.0))
    panel.add_view(look_at_c2w(np.array([-0.3, 0.2, 0.2]), np.array([0.0, 0.0, 2.0])), np.deg2rad(60.0))
    assert server.scene.get_handle_by_name("/camera_path/line") is not None
    assert server.scene.get_handle_by_name("/camera_path/view_002") is not None
    panel.seconds.value, panel.fps.value, panel.size.value = 0.5, 12, "320x240"
    path = panel.render_video()
    assert path == tmp_path / "camera_path.mp4"
    frames, size, fps = read_mp4(path)
    assert len(frames) == 6 and size == (320, 240) and fps == 12.0
    assert panel.progress.value == 100.0 and panel.frames_done == 6
    # the first frame looks from the first view: the red wall left, the blue panel right
    f = frames[0].astype(int)
    assert f[120, 100, 0] > f[120, 100, 2] + 60 and f[120, 230, 2] > f[120, 230, 0] + 60
    panel.remove_last()
    assert len(panel.c2ws) == 2 and server.scene.get_handle_by_name("/camera_path/view_002") is None
    panel.clear()
    assert not panel.c2ws and server.scene.get_handle_by_name("/camera_path/view_000") is None


def test_video_panel_cancel_leaves_no_file(video_panel, tmp_path):
    panel = video_panel
    panel.add_view(np.eye(4), np.deg2rad(60.0))
    panel.add_view(oblique_camera(), np.deg2rad(60.0))
    panel.seconds.value, panel.fps.value, panel.size.value = 20.0, 30, "320x240"   # 600 frames
    result = {}
    t = threading.Thread(target=lambda: result.setdefault("path", panel.render_video()))
    t.start()
    wait_until(lambda: panel.frames_done >= 2, 60, what="two frames")
    panel.cancel()
    t.join(30)
    assert result["path"] is None and panel.frames_done < 600
    assert list(tmp_path.iterdir()) == [] and "cancelled" in panel.info.content
    assert not panel.render_button.disabled
