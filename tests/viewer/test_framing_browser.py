"""Keyframe frustums must not hide the map (issue 45 item 2): a room mapped by a camera walking
into it with 40 keyframes (the 7-Scenes "tunnel of frustums"): the default view the server sends
frames the map (its points cover at least 30 % of that view), the page looks exactly there, and in
its own render, without touching the camera, map pixels cover at least 30 % of the canvas (map
pixels: those that change when the page hides /map; frustum images and background do not). Only the
newest keyframes carry images, and 'Show keyframes' hides them. Chromium for the page; polling only."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common import CHROMIUM, changed_pixels  # benchmarks/common.py, on sys.path via conftest
from helpers.browser import connect, poll_render, render
from helpers.viewer import INTR, apply_snapshot, wait_until

pytestmark = [pytest.mark.browser,
              pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} not installed")]


def room_snapshot(keyframes: int = 40, n: int = 12000):
    """Walls and floor of a 3 x 2 x 3.5 m room, and a camera walking 2 m into it, a keyframe per step."""
    from app.snapshot import KeyframeView, MapSnapshot
    from splat_core.gaussians import GaussianMap

    rng = np.random.default_rng(0)
    u, v = rng.uniform(0, 1, n), rng.uniform(0, 1, n)
    wall = rng.integers(0, 4, n)                                  # back, left, right, floor
    x = np.select([wall == 0, wall == 1, wall == 2], [3 * u - 1.5, -1.5, 1.5], 3 * u - 1.5)
    y = np.select([wall == 3], [1.0], 2 * v - 1.0)
    z = np.select([wall == 0, wall == 3], [4.0, 0.5 + 3.5 * v], 0.5 + 3.5 * u)
    colors = np.stack([0.3 + 0.5 * u, 0.4 + 0.4 * v, 0.5 + 0.1 * wall], 1).astype(np.float32).clip(0, 1)
    arrays = GaussianMap.from_points(np.c_[x, y, z], colors, np.full(n, 0.05), 0, opacity=0.95).to_numpy()
    c2ws, views = [], []
    for k in range(keyframes):
        c2w = np.eye(4)
        c2w[:3, 3] = (0.1 * np.sin(k / 4), -0.05 * np.cos(k / 5), 2.0 * k / keyframes)
        c2ws.append(c2w)
        views.append(KeyframeView(k, c2w, np.full((75, 100, 3), (255, 0, 255), np.uint8)))
    return MapSnapshot(keyframes + 1, "running", keyframes - 1, 300, 1, arrays, tuple(views), INTR,
                       estimated_c2w=np.stack(c2ws))


def view_coverage(means: np.ndarray, position, look_at, fov_y: float, width=80, height=60) -> float:
    """Share of a width x height image that the map's points fall on, seen from `position` looking at
    `look_at` (up -y, OpenCV axes) with vertical field of view fov_y: each point marks its pixel."""
    z = np.asarray(look_at, np.float64) - position
    z /= np.linalg.norm(z)
    x = np.cross(np.array([0.0, -1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    p = (np.asarray(means, np.float64) - position) @ np.stack([x, y, z]).T
    p = p[p[:, 2] > 0.01]
    f = 0.5 * height / np.tan(0.5 * fov_y)
    u, v = (f * p[:, 0] / p[:, 2] + width / 2).astype(int), (f * p[:, 1] / p[:, 2] + height / 2).astype(int)
    hit = np.zeros((height, width), bool)
    keep = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    hit[v[keep], u[keep]] = True
    return float(hit.mean())


def look_direction(position, look_at) -> np.ndarray:
    d = np.asarray(look_at, np.float64) - np.asarray(position, np.float64)
    return d / np.linalg.norm(d)


def test_default_view_frames_the_map_and_the_frustums_stay_out_of_its_way(browser, server):
    from app.viewer import build_viewer

    class Source:
        snap = None

        def latest(self):
            return self.snap

    source = Source()
    app = build_viewer(server, source)
    try:
        page, client = connect(browser, server)
        snap = room_snapshot()
        apply_snapshot(app, source, snap)
        assert len(app.camera_layer.keyframe_frames) == 40 and app.camera_layer.image_frames == [37, 38, 39]
        # where it is decided: the view the server sends every page that has not moved its camera
        position, look_at, _ = app.framing.view
        fov = float(server.initial_camera.fov)
        assert view_coverage(snap.gaussians["means"], position, look_at, fov) >= 0.30
        # the page reports that very pose: its position, and its direction (viser's position setter
        # carries the old look-at along; set before the look-at it pointed the page elsewhere)
        ours = look_direction(position, look_at)
        wait_until(lambda: np.allclose(client.camera.position, position, atol=1e-2)
                   and float(look_direction(client.camera.position, client.camera.look_at) @ ours) > 0.9999,
                   60, what="the page framed")
        assert app.framing.follows(client.client_id)
        # and renders it: map pixels on 30 % of the canvas. Splats stream in and fade in over several
        # renders (slowly on a loaded machine): wait for the state, fail if it never comes.
        last = [render(client)]

        def settled(img):               # the map hidden: frustum images decode, two renders agree
            still, last[0] = changed_pixels(img, last[0]) < 20, img
            return still
        shadow = client.scene.add_frame("/map", show_axes=False, visible=False)
        no_map = poll_render(client, settled, 60, "map hidden settled")
        shadow.remove()

        def coverage(img):
            return changed_pixels(img, no_map) / (img.shape[0] * img.shape[1])
        full = poll_render(client, lambda img: coverage(img) >= 0.30, 180, "map pixels on 30% of the canvas")
        # the frustums are there (hiding them changes pixels), and 'Show keyframes' hides them
        app.panels.show_keyframes.value = False
        assert not app.camera_layer.root.visible
        poll_render(client, lambda img: changed_pixels(img, full) > 30, 60, "keyframes hidden")
        assert app.framing.follows(client.client_id)   # nothing moved the page's camera but us
        assert page.errors == [] and page.external_requests == []
        page.close()
    finally:
        app.close()
