"""Who owns a page's camera (app/viewer/framing.py), without a browser: a page's own start-up pose
does not take the camera from the framing, a look-at point moved along the same ray (orbit target
reset) keeps it ours, and any other pose reported after the page showed ours is the visitor's."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from app.viewer.framing import MapFraming, framing_view
from helpers.viewer import MessageLog


class FakeCamera:
    def __init__(self):
        self.position, self.look_at, self.up_direction = np.zeros(3), np.array([0.0, 0.0, 1.0]), None
        self.image_width = 0                       # 0 until the page's first report (viser's rule)
        self.callbacks = []

    def on_update(self, cb):
        self.callbacks.append(cb)

    def report(self, position, look_at):
        """The page reports a pose (what viser's camera message does)."""
        self.position, self.look_at = np.asarray(position, float), np.asarray(look_at, float)
        self.image_width = 640
        for cb in self.callbacks:
            cb(self)


class FakeClient:
    def __init__(self, client_id):
        self.client_id, self.camera, self._websock_connection = client_id, FakeCamera(), MessageLog()

    def atomic(self):
        return Atomic()


class Atomic:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def make(clients):
    initial = SimpleNamespace(position=(3.0, 3.0, 3.0), look_at=(0.0, 0.0, 0.0), fov=np.radians(75))
    server = SimpleNamespace(initial_camera=initial, get_clients=lambda: {c.client_id: c for c in clients})
    framing = MapFraming(server)
    for c in clients:
        framing.attach(c)
    return framing


def snapshot():
    rng = np.random.default_rng(1)
    means = rng.uniform([-1, -1, 2], [1, 1, 4], (500, 3))
    return SimpleNamespace(gaussians={"means": means}, estimated_c2w=np.eye(4)[None])


def in_view(points, position, look_at, fov_y):
    """Which points a camera at `position` looking at `look_at` (up -y) sees within a square of fov_y."""
    z = (np.asarray(look_at) - position) / np.linalg.norm(np.asarray(look_at) - position)
    x = np.cross([0.0, -1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    p = (points - position) @ np.stack([x, y, z]).T
    t = np.tan(0.5 * fov_y)
    return (p[:, 2] > 0) & (np.abs(p[:, 0]) <= t * p[:, 2] + 1e-9) & (np.abs(p[:, 1]) <= t * p[:, 2] + 1e-9)


def test_framing_view_looks_at_the_map_from_behind_the_first_camera_and_fills_the_view():
    means = snapshot().gaussians["means"]
    fov = np.radians(60)
    position, look_at, radius = framing_view(means, np.eye(4), fov)
    assert position[2] < means[:, 2].min() and position[1] < 0       # behind (-z) and above (-y)
    assert np.allclose(look_at, 0.5 * (np.percentile(means, 5, 0) + np.percentile(means, 95, 0)))
    assert abs(in_view(means, position, look_at, fov).mean() - 0.9) < 0.02     # 90 % in view: no more
    closer = look_at + 0.9 * (position - look_at)
    assert in_view(means, closer, look_at, fov).mean() < 0.85                  # a step closer loses some


def test_a_page_follows_the_framing_until_its_visitor_moves_the_camera():
    page = FakeClient(1)
    framing = make([page])
    assert framing.update(snapshot())
    position, look_at, _ = framing.view
    cam, sent = page.camera, page._websock_connection.placed()
    assert np.allclose(sent["position"], position) and np.allclose(sent["look_at"], look_at)
    cam.report((3.0, 3.0, 3.0), (0.5, 0.0, 0.0))          # its own start-up pose, before it showed ours
    assert framing.follows(1)
    cam.report(position, look_at)                          # it shows ours
    cam.report(position, position + 0.3 * (look_at - position))   # orbit target reset on the same ray
    assert framing.follows(1)
    turned = look_at + np.array([0.5, 0.0, 0.0])           # same place, another direction: the visitor's
    cam.report(position, turned)
    assert not framing.follows(1)
    # a reframing no longer moves that page
    moved = snapshot()
    moved.gaussians["means"] = moved.gaussians["means"] + np.array([2.0, 0.0, 0.0])
    before = len(page._websock_connection.messages)
    assert framing.update(moved)
    assert len(page._websock_connection.messages) == before


def test_a_pose_reported_before_the_page_was_attached_counts():
    """viser runs the connect callback (attach) on a thread pool after the page's first report, so
    the page's report of the initial camera can come before attach: attach judges the pose the page
    already has, and a pose the visitor sets after it is theirs."""
    page = FakeClient(1)
    framing = make([])
    page.camera.report((3.0, 3.0, 3.0), (0.0, 0.0, 0.0))        # the initial camera, before attach
    framing.attach(page)
    assert framing.acknowledged(1) and framing.follows(1)
    page.camera.report((0.5, 0.0, 0.8), (0.5, 0.0, 2.0))        # the visitor's
    assert not framing.follows(1)
    other = FakeClient(2)                                        # a page reporting another pose first
    other.camera.report((1.0, 2.0, 3.0), (0.0, 0.0, 0.0))
    framing.attach(other)
    assert not framing.acknowledged(2) and framing.follows(2)
