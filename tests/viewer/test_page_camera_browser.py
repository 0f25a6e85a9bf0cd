"""A page's camera placed by app/viewer/page_camera.py, in Chromium: each placement, made while the
page may still be reporting the one before, is the pose the page reports (position, look-at, and for
a camera-to-world pose its rotation: the axis conventions round trip). Polling only."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common import CHROMIUM  # benchmarks/common.py, on sys.path via conftest
from helpers.browser import connect
from helpers.viewer import wait_until
from splat_core.camera import rotmat_to_quat, se3_exp

pytestmark = [pytest.mark.browser,
              pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} not installed")]


def test_the_page_reports_the_pose_it_was_given(browser):
    from app.commands.viewer import start_server
    from app.viewer.page_camera import place, place_c2w

    server = start_server("127.0.0.1", 0)
    try:
        page, client = connect(browser, server)
        for k in range(6):
            position, look_at = (0.3 * k, -0.1 * k, -3.0 + 0.2 * k), (0.0, 0.1 * (k % 2), 1.0)
            place(client, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0))          # no waiting between the two
            place(client, position, look_at)
            wait_until(lambda: np.allclose(client.camera.position, position, atol=1e-3)
                       and np.allclose(client.camera.look_at, look_at, atol=1e-3), 30,
                       what=f"the page at {position} looking at {look_at}")
        c2w = se3_exp(np.array([-0.35, 0.6, 0.1]), np.zeros(3))
        c2w[:3, 3] = (0.5, -0.3, 0.2)
        place_c2w(client, c2w)
        wait_until(lambda: np.allclose(client.camera.position, c2w[:3, 3], atol=1e-3), 30, what="the keyframe pose")
        want = rotmat_to_quat(c2w[:3, :3])
        wxyz = np.asarray(client.camera.wxyz)
        assert min(np.abs(wxyz - want).max(), np.abs(wxyz + want).max()) < 1e-3
        assert not page.errors
    finally:
        server.stop()
