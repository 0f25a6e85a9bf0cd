"""The viewer's tools in a real browser (as test_viewer_browser.py): measuring by clicking the
canvas, a camera-path MP4 made from views taken in the page, and the export panel's download."""

from __future__ import annotations

import numpy as np
import pytest

from splat_core.camera import Intrinsics, invert_pose, pose_matrix, project, quat_to_rotmat_np

from helpers.maps import A, B, snapshot_of, two_walls
from helpers.browser import connect, look
from helpers.viewer import wait_until

pytestmark = [pytest.mark.browser]


def click_at(page, client, point) -> None:
    """Click the canvas where the world `point` appears in the client's camera."""
    cam = client.camera
    W, H = int(cam.image_width), int(cam.image_height)
    c2w = pose_matrix(quat_to_rotmat_np(np.asarray(cam.wxyz)), np.asarray(cam.position))
    p_cam = invert_pose(c2w)[:3, :3] @ point + invert_pose(c2w)[:3, 3]
    u, v = project(p_cam, Intrinsics.from_fov(float(cam.fov), W, H))
    box = page.locator("canvas").first.bounding_box()
    page.mouse.click(box["x"] + (u + 0.5) * box["width"] / W, box["y"] + (v + 0.5) * box["height"] / H)


def place_and_hold(client, position, look_at) -> None:
    """Move the browser camera and wait until it stays there: just after connecting, the page
    may still report its own starting camera once after the server's (seen in Chromium)."""
    still = []

    def settled():
        if np.allclose(client.camera.position, position, atol=1e-3):
            still.append(1)
        else:
            still.clear()
            look(client, position, look_at)
        return len(still) >= 8
    wait_until(settled, 30, interval=0.25, what=f"camera at {position}")


def open_folder(page, title: str) -> None:
    page.get_by_text(title, exact=True).first.click()


def test_measure_video_and_export_in_the_page(browser, server, tmp_path):  # noqa: F811
    from app.video import read_mp4
    from app.viewer import StaticSource, build_viewer
    from app.viewer.export_panel import LABELS
    from splat_core.io.map_files import read_map_file

    pytest.importorskip("imageio_ffmpeg", reason="imageio-ffmpeg not installed")
    snap = snapshot_of(two_walls())
    app = build_viewer(server, StaticSource(snap), export_dir=tmp_path, render_backend="cpu")
    try:
        page, client = connect(browser, server)
        place_and_hold(client, (0.0, 0.0, 0.0), (0.0, 0.0, 2.0))
        # measure: two clicks on the canvas -> two points from our depth render, a line and a label
        app.measure.enabled.value = True
        # the page turns scene clicks on when the server's message arrives: click until one lands
        wait_until(lambda: click_at(page, client, A) or app.measure.points, 30, interval=1.0, what="a click")
        # a click of that loop may still be on its way and land after any clear (one arriving late
        # made the first point, the next click a second, and B a third, seen in CI): measure A to B
        # until the two points are A and B, each try from a cleared tool

        def measured():
            app.measure.clear()
            try:
                click_at(page, client, A)
                wait_until(lambda: len(app.measure.points) >= 1, 30, what="first point")
                click_at(page, client, B)
                wait_until(lambda: app.measure.distance is not None, 30, what="distance")
            except AssertionError:          # a stray click took one of ours: try again
                return False
            points = list(app.measure.points)
            return len(points) == 2 and np.linalg.norm(points[0] - A) < 0.01 and np.linalg.norm(points[1] - B) < 0.01
        wait_until(measured, 120, interval=0.0, what="a measurement from A to B")
        assert abs(app.measure.distance - np.linalg.norm(A - B)) < 0.01
        # the distance is set before the line and label are drawn (under the tool's lock): wait for them
        wait_until(lambda: server.scene.get_handle_by_name("/measure/label") is not None, 60, what="label")
        click_at(page, client, A)                       # a third click starts a new measurement
        wait_until(lambda: len(app.measure.points) == 1 and app.measure.distance is None, 30, what="restart")
        app.measure.enabled.value = False
        # camera path: two views added with the page's button, then Render MP4 downloads the video
        panel = app.video_panel
        open_folder(page, "Camera path video")
        page.get_by_role("button", name="Add current view").click()
        wait_until(lambda: len(panel.c2ws) == 1, 60, what="first view")
        place_and_hold(client, (0.3, -0.2, 0.2), (0.0, 0.0, 2.0))
        page.get_by_role("button", name="Add current view").click()
        wait_until(lambda: len(panel.c2ws) == 2, 60, what="second view")
        assert np.allclose(panel.c2ws[0][:3, 3], 0.0, atol=1e-3) and np.allclose(panel.c2ws[1][:3, 3], (0.3, -0.2, 0.2), atol=1e-3)
        panel.seconds.value, panel.fps.value, panel.size.value = 0.5, 10, "320x240"
        with page.expect_download(timeout=120_000) as download:
            page.get_by_role("button", name="Render MP4").click()
        assert download.value.suggested_filename == "camera_path.mp4"
        saved = tmp_path / "downloaded.mp4"
        download.value.save_as(saved)
        frames, size, fps = read_mp4(saved)
        assert len(frames) == 5 and size == (320, 240)
        # export panel: .spz through the page
        app.export_panel.format.value = LABELS["spz"]
        with page.expect_download(timeout=60_000) as download:
            page.get_by_role("button", name="Export and download").click()
        assert download.value.suggested_filename == "map.spz"
        download.value.save_as(tmp_path / "downloaded.spz")
        assert len(read_map_file(tmp_path / "downloaded.spz")["means"]) == snap.num_gaussians
        assert page.errors == [] and page.external_requests == []
        page.close()
    finally:
        app.close()


def test_each_page_chooses_its_own_export_format(browser, server, tmp_path):  # noqa: F811
    """Choosing .spz on one page leaves another page (and a new one) at .ply; each page's button
    exports what that page chose."""
    from app.viewer import StaticSource, build_viewer
    from app.viewer.export_panel import LABELS

    app = build_viewer(server, StaticSource(snapshot_of(two_walls())), export_dir=tmp_path, render_backend="cpu")

    def open_page():
        page = browser.new_page(viewport={"width": 900, "height": 700}, accept_downloads=True)
        page.goto(f"http://127.0.0.1:{server.get_port()}/")
        page.get_by_label("Format").wait_for(timeout=60_000)
        return page

    def exported(page) -> str:
        with page.expect_download(timeout=60_000) as download:
            page.get_by_role("button", name="Export and download").click()
        return download.value.suggested_filename

    try:
        first, second = open_page(), open_page()
        first.get_by_label("Format").click()
        first.get_by_role("option", name=LABELS["spz"]).click()
        wait_until(lambda: "spz" in {app.export_panel.selected_format(c) for c in app.control_gui.clients},
                   20, what="the first page's choice reaches the server")
        assert exported(first) == "map.spz"
        assert second.get_by_label("Format").input_value() == LABELS["ply"]
        assert exported(second) == "map.ply"
        third = open_page()
        assert third.get_by_label("Format").input_value() == LABELS["ply"]
        assert first.get_by_label("Format").input_value() == LABELS["spz"]
        for page in (first, second, third):
            page.close()
    finally:
        app.close()
