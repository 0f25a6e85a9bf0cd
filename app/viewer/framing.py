"""The default view: a camera that frames the map, kept framing it while the map grows, on every
page until its visitor moves the camera (then the page is theirs).

The view looks at the middle of the box holding 90% of the map's Gaussians, from behind and
above the first camera, as close as keeps 90 % of them in a square of the page's vertical field
of view (a sphere around the box fitted to the view left most of the canvas empty).
New pages start there (`server.initial_camera`); pages whose camera is still where this class
last put it follow each new framing. A camera anywhere else (the visitor dragged it, clicked a
keyframe, typed a pose) is the visitor's: it is never moved again.
"""

from __future__ import annotations

import threading

import numpy as np
import viser

from ..snapshot import MapSnapshot
from .page_camera import place

BEHIND_ABOVE = np.array([0.0, -0.5, -1.0])   # in the first camera's axes: back (-z) and up (-y)
REFRAME_FRACTION = 0.05                       # reframe when the view moves this much of the map's size
SENT_KEPT = 6                                 # poses sent to a page that still count as ours
IN_VIEW = 0.9                                 # the share of the map's points the default view keeps in view
MAX_POINTS = 20000                            # points sampled for the fit
DIRECTION_COS = np.cos(np.radians(0.5))       # a page looking this close to our direction looks where we put it


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-12 else v


def framing_view(means: np.ndarray, first_c2w: np.ndarray, fov_y: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(camera position, look-at point, radius) framing the map `means` (N,3), seen from behind
    and above the camera `first_c2w`: as close as keeps IN_VIEW of the points inside the vertical
    field of view and a square around it (the page's panel covers the right of a wide canvas)."""
    pts = np.asarray(means, np.float64)
    if len(pts) > MAX_POINTS:
        pts = pts[np.random.default_rng(0).choice(len(pts), MAX_POINTS, replace=False)]
    lo, hi = np.percentile(pts, [5, 95], axis=0)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 0.05)
    first_c2w = np.asarray(first_c2w, np.float64)
    eye = first_c2w[:3, 3] + first_c2w[:3, :3] @ BEHIND_ABOVE * radius
    back = _unit(eye - centre)
    if float(np.linalg.norm(eye - centre)) <= 1e-9:
        back = first_c2w[:3, :3] @ _unit(BEHIND_ABOVE)
    # camera axes looking along -back with up -y; each point needs the camera at least this far back
    right = _unit(np.cross(np.array([0.0, -1.0, 0.0]), -back))
    if float(np.linalg.norm(right)) < 0.5:           # looking straight up or down
        right = first_c2w[:3, 0]
    down = np.cross(-back, right)
    rel = pts - centre
    lateral = np.maximum(np.abs(rel @ right), np.abs(rel @ down))
    needed = lateral / np.tan(0.5 * fov_y) + rel @ back
    distance = max(float(np.percentile(needed, 100 * IN_VIEW)), 0.25 * radius)
    return centre + back * distance, centre, radius


class MapFraming:
    """Frames the map for new pages and for pages whose visitor has not moved the camera."""

    def __init__(self, server: viser.ViserServer):
        self.server = server
        self.view: tuple | None = None          # (position, look_at, radius) last framed
        self._sent: dict[int, list] = {}        # client -> poses this class gave its camera
        self.moved: set[int] = set()            # clients whose visitor took over the camera
        self._acked: set[int] = set()           # clients that have reported a pose of ours
        self._lock = threading.Lock()

    def attach(self, client: viser.ClientHandle) -> None:
        cam = self.server.initial_camera
        with self._lock:
            self._sent[client.client_id] = [(np.array(cam.position, np.float64), np.array(cam.look_at, np.float64))]
        client.camera.on_update(lambda camera: self._on_camera(client.client_id, camera))
        # viser runs this (a connect callback) on its thread pool after the page's first camera
        # report, and may handle the page's next reports before it: judge the pose it already has
        if client.camera.image_width > 0:
            self._on_camera(client.client_id, client.camera)

    def detach(self, client_id: int) -> None:
        with self._lock:
            self._sent.pop(client_id, None)
            self.moved.discard(client_id)
            self._acked.discard(client_id)

    def follows(self, client_id: int) -> bool:
        return client_id in self._sent and client_id not in self.moved

    def acknowledged(self, client_id: int) -> bool:
        """Whether the page has reported a pose this class gave it (from then on, any other pose it
        reports is its visitor's)."""
        return client_id in self._acked

    def _on_camera(self, client_id: int, camera) -> None:
        position = np.asarray(camera.position, np.float64)
        with self._lock:
            sent = self._sent.get(client_id)
            if sent is None or client_id in self.moved:
                return
            tol = 1e-3 * max(1.0, float(np.linalg.norm(sent[-1][0] - sent[-1][1])))
            # the position and the direction, not the look-at point: a page reports look-at points of
            # its own along the same ray (orbit target resets) while its camera stays put
            direction = _unit(np.asarray(camera.look_at, np.float64) - position)
            ours = any(np.allclose(position, p, atol=tol) and float(direction @ _unit(q - p)) > DIRECTION_COS
                       for p, q in sent)
            if ours:
                self._acked.add(client_id)
            elif client_id in self._acked:     # before that, a page reports its own start-up pose
                self.moved.add(client_id)

    def update(self, snap: MapSnapshot) -> bool:
        """Frame `snap`'s map if it moved the view enough; returns True when the view changed."""
        means = snap.gaussians["means"]
        if len(means) < 10:
            return False
        first = snap.estimated_c2w[0] if len(snap.estimated_c2w) else np.eye(4)
        fov = float(self.server.initial_camera.fov)
        position, look_at, radius = framing_view(means, first, fov)
        if self.view is not None:
            old_position, old_look_at, _ = self.view
            moved = max(np.linalg.norm(position - old_position), np.linalg.norm(look_at - old_look_at))
            if moved < REFRAME_FRACTION * radius:
                return False
        self.view = (position, look_at, radius)
        initial = self.server.initial_camera
        initial.look_at, initial.position = tuple(look_at), tuple(position)
        for client in list(self.server.get_clients().values()):
            with self._lock:
                if not self.follows(client.client_id):
                    continue
                sent = self._sent[client.client_id]
                sent.append((position.copy(), look_at.copy()))
                del sent[:-SENT_KEPT]
            place(client, position, look_at)
        return True
