"""A browsed run folder whose metrics.json lists a closed loop, in headless Chromium: the page says
what happened and how many loops, the loop edge is drawn between the two keyframes, and a page
scrubbed to a keyframe shows only the loops closed by then. Skipped without /usr/bin/chromium."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from common import CHROMIUM  # noqa: F401 (benchmarks/common.py, on sys.path via conftest)
from helpers.browser import connect, count, look, poll_render
from helpers.runs import make_run
from helpers.viewer import wait_until

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} not installed (apt-get install chromium)"),
]

LOOP = dict(keyframes=[0, 2], frames=[0, 2], inliers=31, applied=True, correction_cm=4.1, correction_deg=0.35,
            disagreement_cm=4.3, disagreement_deg=0.4, seconds=0.8)


def cyan(img):
    return count(img, (0, 180, 170), (130, 255, 255))   # the edge as lit: about (90, 205, 200)


def test_browsed_run_with_a_loop_shows_the_loop(browser, server, tmp_path):
    from app.browse import load_run
    from app.snapshot import KeyframeView
    from app.viewer import build_viewer
    from app.viewer.app import StaticSource

    run = make_run(tmp_path)                                  # 3 poses at x = 0, 0.1, 0.2
    (run / "metrics.json").write_text(json.dumps({"loops_closed": 1, "loops": [LOOP]}))
    snap = load_run(run)
    thumb = np.full((30, 40, 3), 128, np.uint8)
    keyframes = tuple(KeyframeView(f, snap.estimated_c2w[f], thumb) for f in range(3))   # no checkpoint: made here
    app = build_viewer(server, StaticSource(dataclasses.replace(snap, keyframes=keyframes)))
    try:
        page, client = connect(browser, server)
        line = "loop closed: keyframe 0 <-> 2 (frames #0 <-> #2), correction 4.1 cm, 0.35°"
        page.wait_for_function(f"() => document.body.innerText.includes({json.dumps(line)})", timeout=60_000)
        assert "keyframes: 3 · loops: 1" in page.inner_text("body")
        assert np.allclose(app.loop_layer.segments, [[[0, 0, 0], [0.2, 0, 0]]])
        for name in ("/map", "/trajectory"):                                   # the trajectory runs along the edge
            client.scene.add_frame(name, show_axes=False, visible=False)
        look(client, (0.1, -0.1, -0.3), (0.1, 0.0, 0.0))
        poll_render(client, lambda img: cyan(img) > 30, 60, "loop edge")
        hidden = client.scene.add_frame("/keyframes/loops", show_axes=False, visible=False)
        poll_render(client, lambda img: cyan(img) < 5, 60, "no loop edge")      # the colour was the edge's
        hidden.remove()
        scrub = wait_until(lambda: app.scrubber.pages.get(client.client_id), 60, what="the page's scrubber")
        app.scrubber.go_to(client.client_id, 1, fly=False)                    # keyframe at frame 1: before the loop
        assert "/keyframes" in scrub.shadows and "/scrub/loops" not in scrub.shadows
        app.scrubber.go_to(client.client_id, 2, fly=False)                    # frame 2 closed it
        assert np.allclose(scrub.shadows["/scrub/loops"].points, app.loop_layer.segments)
        assert page.errors == [] and page.external_requests == []
        page.close()
    finally:
        app.close()
