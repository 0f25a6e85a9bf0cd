"""Placing a page's camera: the whole pose, every time.

Why not viser's setters (`client.camera.position = ...; client.camera.look_at = ...`): in viser
1.1.1 each setter skips an assignment equal to the pose the server holds, and the position setter
sends a look-at of its own (the old one carried along). The server's copy of the pose is replaced
by every camera report from the page, on viser's event-loop thread, so a report that arrives
between two setters (the page reporting its start-up pose, or its last move) can make the second
one skip: the page then ends at the new position looking along the carried look-at, not the one
asked for: once in 40 placements on a page just connected, with a busy loop beside it, and once in
CI (a test's page never reached the camera it was given). In the viewer that is a page left
looking the wrong way, and MapFraming then taking that pose for the visitor's own.

So for the viser versions page_shim.py knows, the three messages (up, position, look-at) are
queued as one atomic group, whatever the server last heard; the page's next report updates the
server's copy. Other versions fall back to the setters.
"""

from __future__ import annotations

import numpy as np

from .page_shim import applies

UP = (0.0, -1.0, 0.0)        # the page's up: our world's -y (OpenCV cameras, y down)


def place(client, position, look_at, up=UP) -> None:
    """Put the page's camera at `position`, looking at `look_at`, with `up` as its orbit's up."""
    position, look_at, up = (tuple(float(v) for v in np.asarray(x, np.float64).reshape(3))
                             for x in (position, look_at, up))
    if not applies():
        with client.atomic():
            client.camera.up_direction = up
            client.camera.position = position
            client.camera.look_at = look_at
        return
    from viser import _messages
    with client.atomic():
        for message in (_messages.SetCameraUpDirectionMessage(up), _messages.SetCameraPositionMessage(position),
                        _messages.SetCameraLookAtMessage(look_at)):
            client._websock_connection.queue_message(message)


def place_c2w(client, c2w: np.ndarray) -> None:
    """Put the page's camera at a camera-to-world pose (OpenCV axes: +z forward, -y up). The orbit
    point is ahead of it at the page's current orbit distance; the orbit's up is the page's up
    tilted into the plane of the new view's up and forward (so the view keeps its roll and the
    orbit stays as upright as it was), or the view's own up when that plane is nearly edge-on."""
    c2w = np.asarray(c2w, np.float64)
    position, forward, right = c2w[:3, 3], c2w[:3, 2], c2w[:3, 0]
    view_up = -c2w[:3, 1]
    try:
        old_up = np.asarray(client.camera.up_direction, np.float64)
        distance = float(np.linalg.norm(np.asarray(client.camera.look_at) - np.asarray(client.camera.position)))
    except AssertionError:                  # no report from the page yet
        old_up, distance = np.asarray(UP), 1.0
    up = old_up - float(old_up @ right) * right
    norm = float(np.linalg.norm(up))
    if norm < 1e-6 or float(up @ view_up) / norm < 0.05:
        up = view_up
    place(client, position, position + forward * (distance if distance > 1e-6 else 1.0), up)
