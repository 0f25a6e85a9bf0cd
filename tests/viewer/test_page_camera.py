"""Placing a page's camera (app/viewer/page_camera.py) sends the whole pose whatever the server last
heard from the page: a camera report from the page that replaced the server's copy of the pose
between two of viser's setters made the second one skip, and left a page looking the wrong way."""

from __future__ import annotations

import contextlib
from types import SimpleNamespace

import numpy as np
import pytest

from helpers.viewer import MessageLog
from splat_core.camera import se3_exp


class RecordingClient:
    """A ClientHandle's surface as page_camera uses it: a camera holding the pose the page last
    reported, the messages queued for the page, and how many atomic groups were opened."""

    def __init__(self, position, look_at, up=(0.0, -1.0, 0.0)):
        self.groups = 0
        self._websock_connection = MessageLog()
        self.camera = SimpleNamespace(position=np.asarray(position, np.float64),
                                      look_at=np.asarray(look_at, np.float64), up_direction=np.asarray(up, np.float64))

    @contextlib.contextmanager
    def atomic(self):
        self.groups += 1
        yield


def test_the_whole_pose_is_sent_even_where_the_server_already_holds_part_of_it():
    from app.viewer.page_camera import place
    from app.viewer.page_shim import applies
    if not applies():
        pytest.skip("page_camera.py sends viser's messages itself only for the viser versions page_shim knows")
    # the server holds the target look-at already (a report from a page still looking there): viser's
    # look_at setter would skip it, while its position setter would send the old look-at carried along
    client = RecordingClient(position=(3.0, 3.0, 3.0), look_at=(0.0, 0.0, 0.0))
    place(client, (0.0, 0.0, -3.0), (0.0, 0.0, 0.0))
    assert client.groups == 1
    messages = client._websock_connection.messages
    assert [type(m).__name__ for m in messages] == [
        "SetCameraUpDirectionMessage", "SetCameraPositionMessage", "SetCameraLookAtMessage"]
    got = client._websock_connection.placed()
    np.testing.assert_allclose(got["position"], (0.0, 0.0, -3.0))
    np.testing.assert_allclose(got["look_at"], (0.0, 0.0, 0.0))
    np.testing.assert_allclose(got["up"], (0.0, -1.0, 0.0))
    assert not any(m.initial for m in messages)


@pytest.mark.parametrize("rotvec", [(0.0, 0.0, 0.0), (-0.45, 0.7, 0.0), (0.2, -1.2, 0.5)],
                         ids=["identity", "yaw-pitch", "rolled"])
def test_a_pose_is_sent_as_its_centre_its_view_direction_and_an_up_in_its_view_plane(rotvec):
    from app.viewer.page_camera import place_c2w
    from app.viewer.page_shim import applies
    if not applies():
        pytest.skip("page_camera.py sends viser's messages itself only for the viser versions page_shim knows")
    c2w = se3_exp(np.array(rotvec), np.zeros(3))
    c2w[:3, 3] = (0.4, -0.2, 1.5)
    client = RecordingClient(position=(0.0, 0.0, -2.0), look_at=(0.0, 0.0, 0.5))     # orbit distance 2.5
    place_c2w(client, c2w)
    got = client._websock_connection.placed()
    np.testing.assert_allclose(got["position"], c2w[:3, 3])
    np.testing.assert_allclose(got["look_at"], c2w[:3, 3] + 2.5 * c2w[:3, 2])
    up = got["up"]
    assert abs(float(up @ c2w[:3, 0])) < 1e-9              # in the view's up-forward plane: no roll
    assert float(up @ -c2w[:3, 1]) > 0.05                  # and on the view's up side
    # the orbit stays as upright as it was: of the ups in that plane, the one nearest the page's old up
    old = np.array([0.0, -1.0, 0.0])
    plane = old - (old @ c2w[:3, 0]) * c2w[:3, 0]
    np.testing.assert_allclose(up / np.linalg.norm(up), plane / np.linalg.norm(plane), atol=1e-9)
