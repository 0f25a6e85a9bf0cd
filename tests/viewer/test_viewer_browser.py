"""The viewer in a real browser: headless Debian Chromium (software WebGL) driven by Playwright
against an in-process server on port 0 (docs/viewer-notes.md §2.3). Small maps, polling, no sleeps for
state. Skipped when /usr/bin/chromium or playwright is missing."""

from __future__ import annotations

import re

import time
from pathlib import Path

import numpy as np
import pytest

from helpers.viewer import FakePipeline, wait_until

from common import CHROMIUM, changed_pixels  # noqa: F401 (benchmarks/common.py, on sys.path via conftest)
from helpers.browser import connect, frames_shown, green, look, poll_render, red, render

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} not installed (apt-get install chromium)"),
]


















def test_live_slam_pause_resume(browser, server, tmp_path):
    """The real pipeline on a tiny synthetic scene: connect, splats and frustums appear,
    pause stops the frame counter, resume continues it, the run folder is written."""
    from app.viewer import build_viewer
    from app.worker import SlamWorker
    from splat_core.config import load_config
    from splat_core.run import Pipeline, open_input

    config = load_config("cpu", {"resolution": [64, 48], "tracking": {"iterations": 4},
                                 "mapping": {"iterations": 4, "first_frame_iterations": 8}})
    pipe = Pipeline(open_input(None, n_frames=300, width=64, height=48), config, tmp_path / "run")
    worker = SlamWorker(pipe, live_max_width=64)
    app = build_viewer(server, worker, export_dir=tmp_path / "run", novel_full_width=160)
    try:
        page, client = connect(browser, server)
        look(client, (0.0, -0.3, -1.0), (0.0, 0.0, 1.5))
        empty = render(client)
        worker.start()
        # pause stops the frame counter; resume continues it
        wait_until(lambda: frames_shown(page) >= 1, 120, what="first frames")
        page.get_by_role("button", name="Pause").click()
        wait_until(lambda: worker.latest().state == "paused", 60, what="paused")
        n = worker.latest().processed
        wait_until(lambda: frames_shown(page) == n, 60, what="counter shows the paused frame")
        time.sleep(2.0)   # nothing may move while paused (a negative check needs a wait)
        assert frames_shown(page) == n and worker.latest().processed == n
        page.get_by_role("button", name="Resume").click()
        wait_until(lambda: frames_shown(page) > n, 120, what="counter moves after resume")
        # splats: the map drawn from behind the first camera changes many pixels
        poll_render(client, lambda img: changed_pixels(img, empty) > 2000, 120, "splats")
        wait_until(lambda: app.camera_layer.keyframe_frames, 60, what="a keyframe frustum")
        # frustums: hiding /keyframes for this client changes pixels
        with_frustums = poll_render(client, lambda img: True)
        shadow = client.scene.add_frame("/keyframes", show_axes=False, visible=False)
        poll_render(client, lambda img: changed_pixels(img, with_frustums) > 30, 30, "frustums hidden")
        shadow.remove()
        assert page.errors == [] and page.external_requests == []
        page.close()
    finally:
        worker.stop(join_timeout=120)
        app.close()
    assert (tmp_path / "run" / "map.ply").is_file() and (tmp_path / "run" / "trajectory.txt").is_file()


def test_points_while_running_then_splats_in_the_browser(browser, server):
    """The map drawn as points while SLAM runs covers about what its splats cover once paused."""
    from app.snapshot import KeyframeView, MapSnapshot
    from app.viewer.scene import MapLayer
    from helpers.viewer import blob_map

    m = blob_map(2000, 0).to_numpy()
    kfs = (KeyframeView(0, np.eye(4), np.zeros((4, 4, 3), np.uint8)),)
    layer = MapLayer(server, running_style="points")
    page, client = connect(browser, server)
    try:
        look(client, (0.0, 0.0, 0.5), (0.0, 0.0, 2.0))
        empty = render(client)
        layer.update(MapSnapshot(1, "running", 0, 10, 1, m, kfs))
        points = poll_render(client, lambda img: changed_pixels(img, empty) > 1500, 60, "points")
        layer.update(MapSnapshot(2, "paused", 0, 10, 2, m, kfs))
        poll_render(client, lambda img: changed_pixels(img, points) > 200, 60, "splats replace points")
        last = [render(client)]

        def settled(img):        # a new splat node fades in: wait until two renders agree
            still, last[0] = changed_pixels(img, last[0]) < 20, img
            return still
        splats = poll_render(client, settled, 60, "splats faded in")
        covered_points, covered_splats = changed_pixels(points, empty), changed_pixels(splats, empty)
        assert 0.5 < covered_points / covered_splats < 2.0, (covered_points, covered_splats)
        assert page.errors == [] and page.external_requests == []
    finally:
        page.close()


def test_keyframe_slider_novel_view_and_download(browser, server, tmp_path):
    """A scripted run with one colour per frame: the slider shows the map at a keyframe, the
    novel-view mode sends our render as the background, the PLY download parses."""
    from app.viewer import build_viewer
    from app.worker import SlamWorker
    from splat_core.io.ply import PLY_PROPERTIES, read_ply

    pipe = FakePipeline(total=5, per_frame=2000, keyframe_every=2, out_dir=tmp_path)
    worker = SlamWorker(pipe, live_render=False)
    app = build_viewer(server, worker, export_dir=tmp_path, novel_full_width=200, novel_low_width=64)
    try:
        worker.start()
        wait_until(lambda: app.applied is not None and app.applied.state == "finished", 30, what="run end")
        page, client = connect(browser, server)
        for name in ("/keyframes", "/trajectory", "/camera"):   # count map colours only
            client.scene.add_frame(name, show_axes=False, visible=False)
        look(client, (0.5, 0.0, 0.8), (0.5, 0.0, 2.0))
        # the whole map: frame 0 red (keyframe 0) and frame 2 green (keyframe 2)
        poll_render(client, lambda img: red(img) > 100 and green(img) > 100, 90, "full map")
        # slider to the first keyframe through the page
        row = page.locator("label", has_text=re.compile(r"^Keyframe$")).first.locator("xpath=ancestor::*[.//input][1]")
        box = row.locator("input.mantine-NumberInput-input")
        box.fill("1")                                            # keyframes count from 1
        box.press("Enter")
        scrub = wait_until(lambda: app.scrubber.pages.get(client.client_id), 60, what="the page's scrubber")
        wait_until(lambda: scrub.position == 0 and not scrub.follow.value, 60, what="slider at keyframe 1, not following")
        # the camera flew to keyframe 0 (the first camera)
        wait_until(lambda: np.allclose(client.camera.position, 0.0, atol=1e-3), 60, what="camera at keyframe 0")
        look(client, (0.5, 0.0, 0.8), (0.5, 0.0, 2.0))
        poll_render(client, lambda img: red(img) > 100 and green(img) < 20, 60, "map at keyframe 0")
        wait_until(lambda: "Keyframe 1 / 3" in scrub.info.content, 60, what="keyframe panel")
        # back to the latest map with the checkbox
        page.get_by_label("Follow latest").check()
        poll_render(client, lambda img: green(img) > 100, 60, "latest map again")
        # novel view: our renderer draws the background, WebGL splats hidden for this client
        view = wait_until(lambda: app.novel_views.get(client.client_id), 60, what="novel view")
        view.mode_dropdown.value = "Our render: colour"
        wait_until(lambda: view.frames_sent >= 1, 120, what="a background image")
        assert view._shadow is not None
        poll_render(client, lambda img: red(img) > 100 and green(img) > 100, 60, "our render as background")
        view.mode_dropdown.value = "WebGL splats (fast)"
        assert view._shadow is None
        # PLY download (the Export panel's default format)
        with page.expect_download(timeout=60_000) as download:
            page.get_by_role("button", name="Export and download").click()
        assert download.value.suggested_filename == "map.ply"
        saved = tmp_path / "downloaded.ply"
        download.value.save_as(saved)
        header = saved.read_bytes()[:1000].split(b"end_header")[0].decode()
        assert "element vertex 10000" in header
        assert [line.split()[-1] for line in header.splitlines() if line.startswith("property")] == PLY_PROPERTIES
        assert len(read_ply(saved)["means"]) == 10000
        assert (tmp_path / "exports" / "map.ply").is_file()
        assert page.errors == [] and page.external_requests == []
        page.close()
    finally:
        worker.stop(join_timeout=10)
        app.close()
