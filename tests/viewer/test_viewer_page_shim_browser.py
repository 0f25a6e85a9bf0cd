"""Issue 32, defect 8: no `computeBoundingSphere(): Computed radius is NaN` in the browser console
while the map updates (app/viewer/page_shim.py). The same scripted run is watched on a plain
viser server (the error is there: the check can fail) and on the viewer's server (none), in
headless Chromium with the pointer moving over the 3D view. Polling; the watched interval is
the run itself plus a few seconds."""

from __future__ import annotations

import gzip
import http

import pytest

from helpers.browser import connect, green, look, poll_render, red
from helpers.viewer import FakePipeline, wait_until

NAN_ERROR = "computeBoundingSphere"


def watch_a_run(browser, server, tmp_path):
    """Console messages of a page open while a scripted run adds keyframe chunks (the pointer
    moving over the 3D view meanwhile), and the map layer's sends after the page connected."""
    from app.viewer import build_viewer
    from app.worker import SlamWorker

    pipe = FakePipeline(total=8, per_frame=400, keyframe_every=2, frame_seconds=0.4, out_dir=tmp_path)
    worker = SlamWorker(pipe, live_render=False)
    app = build_viewer(server, worker, export_dir=tmp_path, novel_full_width=64, novel_low_width=32)
    messages = []
    try:
        page, client = connect(browser, server)
        page.on("console", lambda m: messages.append((m.type, m.text)))
        for name in ("/keyframes", "/trajectory", "/camera"):   # count map colours only
            client.scene.add_frame(name, show_axes=False, visible=False)
        # the view stays the test's: the viewer frames the map only for pages whose visitor has not
        # moved the camera (framing.py), so wait until it has seen the page at its start-up pose and
        # then at the test's
        wait_until(lambda: app.framing.acknowledged(client.client_id), 30, what="the page at the viewer's view")
        look(client, (0.5, 0.0, 0.8), (0.5, 0.0, 2.0))
        wait_until(lambda: client.client_id in app.framing.moved, 30, what="the page's camera the test's own")
        sent_before = app.map_layer.chunks_sent
        worker.start()
        step = 0
        while not (app.applied is not None and app.applied.state == "finished"):
            assert step < 600, "the scripted run did not finish"
            page.mouse.move(300 + 12 * (step % 30), 250 + 7 * (step % 11))
            page.wait_for_timeout(50)            # also delivers the page's console events
            step += 1
        sent = app.map_layer.chunks_sent - sent_before
        img = poll_render(client, lambda im: red(im) > 100 and green(im) > 100, 60, "map drawn")
        for i in range(20):                      # a little more pointer after the last update
            page.mouse.move(400 - 10 * i, 300)
            page.wait_for_timeout(50)
        page.close()
        return messages, sent, img
    finally:
        worker.stop(join_timeout=60)
        app.close()


@pytest.mark.browser
def test_plain_viser_logs_the_nan_bounding_sphere(browser, tmp_path):
    """Without the shim (viser's own page) the error is logged: what the next test checks is real."""
    import viser

    from app.viewer.page_shim import applies

    if not applies():
        pytest.skip(f"viser {viser.__version__}: the shim is for other versions")
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        messages, sent, _ = watch_a_run(browser, server, tmp_path)
    finally:
        server.stop()
    assert sent >= 2
    assert sum(NAN_ERROR in text for kind, text in messages if kind == "error") >= 2, messages


@pytest.mark.browser
def test_viewer_page_has_no_nan_bounding_sphere(browser, tmp_path):
    """The viewer's server (start_server, as `splatam-viewer` makes it): several map updates, the
    pointer moving, the map drawn, and no bounding-sphere error."""
    from app.commands.viewer import start_server

    server = start_server("127.0.0.1", 0)
    try:
        messages, sent, _ = watch_a_run(browser, server, tmp_path)
    finally:
        server.stop()
    assert sent >= 2
    assert [text for kind, text in messages if NAN_ERROR in text] == []


def test_page_patch_inserts_the_script_once_and_keeps_gzip_and_length():
    from websockets.datastructures import Headers
    from websockets.http11 import Request, Response

    from app.viewer import page_shim

    if not page_shim.applies():
        pytest.skip("the shim is for another viser version")
    html = "<!doctype html><html><head><title>x</title></head><body></body></html>"
    patched = page_shim.patch_page(html)
    assert patched.index(page_shim.MARKER) < patched.index("<title>") and page_shim.patch_page(patched) == patched
    assert page_shim.patch_page("<p>no head</p>") == "<p>no head</p>"
    body = gzip.compress(html.encode())

    def viser_like(connection, request):
        kind = "text/html; charset=utf-8" if request.path.split("?")[0] in ("/", "/x.html") else "image/png"
        return Response(http.HTTPStatus.OK, "OK", Headers({"Content-Type": kind, "Content-Length": str(len(body)),
                                                           "Content-Encoding": "gzip"}), body)
    serve = page_shim.wrap(viser_like)
    page = serve(None, Request("/?token=abc", Headers()))
    assert gzip.decompress(page.body).decode() == patched
    assert page.headers.get_all("Content-Length") == [str(len(page.body))]
    assert serve(None, Request("/x.png", Headers())).body == body              # other files untouched
    assert serve(None, Request("/x.html", Headers())).body == body             # only the page itself


def test_a_page_that_draws_in_software_is_counted_while_its_websocket_is_open():
    from websockets.datastructures import Headers
    from websockets.http11 import Request
    from websockets.protocol import State

    from app.viewer import page_shim

    class Websocket:
        state = State.CONNECTING

    pages = page_shim.SoftwarePages()
    serve = page_shim.wrap(lambda connection, request: None, pages)   # viser lets handshakes through
    upgrade = Headers({"Upgrade": "websocket", "Connection": "Upgrade"})
    says = f"/?{page_shim.SOFTWARE_PARAM}=software"
    software, gpu, plain = Websocket(), Websocket(), Websocket()
    assert serve(software, Request(says, upgrade)) is None
    assert serve(gpu, Request("/", upgrade)) is None                    # a page with a GPU says nothing
    serve(plain, Request(says, Headers()))                             # not a websocket handshake
    assert pages.count() == 1
    software.state = State.OPEN
    assert pages.count() == 1
    software.state = State.CLOSED
    assert pages.count() == 0


def test_html_export_carries_the_script(tmp_path):
    from app.html_export import html_page
    from app.viewer import page_shim
    from helpers.viewer import blob_map

    if not page_shim.applies():
        pytest.skip("the shim is for another viser version")
    assert page_shim.MARKER in html_page(blob_map(50).to_numpy())


def canvas_centre(page):
    """The mean RGB of the middle of the page's canvas (what the person sees there)."""
    import io

    import numpy as np
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(page.locator("canvas").first.screenshot())), np.float64)
    h, w = img.shape[:2]
    return img[h // 2 - 40:h // 2 + 40, w // 2 - 40:w // 2 + 40, :3].mean(axis=(0, 1))


@pytest.mark.browser
def test_software_webgl_page_holds_redraws_and_still_shows_the_last_change(browser):
    """Headless Chromium draws WebGL in software (SwiftShader): the viewer's page holds its view's
    draws to one per gap while nobody uses it, and the last of a burst of scene changes is still
    drawn on the canvas; get_render captures are never held. `?redraw=full` draws every frame. The
    page tells the server it draws in software while it is open (scene.py's `auto` then draws the map
    as points while SLAM runs)."""
    from app.commands.viewer import start_server
    from app.viewer import page_shim

    server = start_server("127.0.0.1", 0)
    try:
        page, client = connect(browser, server)
        state = page.evaluate("() => window.__splatamRedraw")
        if not state["slow"]:
            pytest.skip("this Chromium draws WebGL with a GPU: the page draws every frame there")
        assert state["software"]              # and it told the server so (through its websocket's URL)
        wait_until(lambda: page_shim.software_pages(server) == 1, 60, what="the page counted as drawing in software")
        look(client, (0.0, 0.0, -3.0), (0.0, 0.0, 0.0))
        box = server.scene.add_box("/box", color=(255, 0, 0), dimensions=(2.0, 2.0, 2.0))
        wait_until(lambda: canvas_centre(page)[0] > canvas_centre(page)[1] + 80, 60, what="red box on the canvas")
        held = page.evaluate("() => window.__splatamRedraw.held")
        for k in range(12):                      # a burst of changes, each asking for 250 ms of frames
            box.color = (255, 0, 0) if k % 2 else (0, 200, 0)
            box.position = (0.0, 0.0, 0.01 * k)
        box.color = (0, 200, 0)                  # the last change: green
        wait_until(lambda: page.evaluate("() => window.__splatamRedraw.held") > held, 60, what="a held draw")
        wait_until(lambda: canvas_centre(page)[1] > canvas_centre(page)[0] + 80, 60, what="green box on the canvas")
        img = poll_render(client, lambda im: im[60:90, 80:120, 1].mean() > im[60:90, 80:120, 0].mean() + 60, 60,
                          "get_render while draws are held")     # 150 x 200: the box in the middle
        assert img.shape[:2] == (150, 200)
        page.close()
        wait_until(lambda: page_shim.software_pages(server) == 0, 60, what="the closed page no longer counted")
        full = browser.new_page(viewport={"width": 400, "height": 300})
        full.goto(f"http://127.0.0.1:{server.get_port()}/?redraw=full")
        full.wait_for_function("() => !document.body.innerText.includes('Connecting')", timeout=60_000)
        assert full.evaluate("() => window.__splatamRedraw.slow") is False
        full.close()
    finally:
        server.stop()
