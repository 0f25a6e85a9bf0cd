"""The viewer as visitors meet it, in headless Chromium (issues 32, 45): plots with values on both axes,
scrubbing that shows the map, slider / label / frustum click in sync, a second page that follows
the latest map, readable live captions, texts that follow the run's state, the first minute,
and tokens with a view-only page. One finished scripted run is served to the whole module;
each test opens its own pages. Polling only, no sleeps."""

from __future__ import annotations

import re
import urllib.error
import urllib.request

import numpy as np
import pytest

from helpers.browser import look, render
from helpers.viewer import FakePipeline, wait_until

pytestmark = [pytest.mark.browser]

GREY = 0.5


class GreyFramePipeline(FakePipeline):
    """Frames captured grey (so frustum images are grey), the map in one colour per frame."""

    def frame(self, k):
        f = super().frame(k)
        f.color[:] = GREY
        return f


def count(img, lo, hi):
    rgb = img[..., :3]
    return int(np.all((rgb >= np.asarray(lo)) & (rgb <= np.asarray(hi)), axis=-1).sum())


def red(img):
    return count(img, (150, 0, 0), (255, 90, 90))


def green(img):
    return count(img, (0, 140, 0), (110, 255, 110))


def grey(img):
    return count(img, (110, 110, 110), (145, 145, 145))


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """(server, app): a finished 5-frame run (keyframes at frames 0, 2, 4), live renders on."""
    import viser

    from app.viewer import build_viewer
    from app.worker import SlamWorker

    out = tmp_path_factory.mktemp("run")
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    worker = SlamWorker(GreyFramePipeline(total=5, per_frame=1000, keyframe_every=2, out_dir=out),
                        live_render=True, render_backend="reference", live_max_width=40, live_interval_s=0.0)
    app = build_viewer(server, worker, export_dir=out, render_backend="reference", update_hz=10, running_update_hz=10, scrub_width=64,
                       novel_full_width=64, novel_low_width=32)
    worker.start()
    wait_until(lambda: app.applied is not None and app.applied.state == "finished", 60, what="run end")
    yield server, app
    app.close()
    server.stop()


def open_page(browser, url, server=None):  # noqa: F811
    """A connected page (and its viser client when `server` is given)."""
    page = browser.new_page(viewport={"width": 900, "height": 600})   # small: software WebGL draws every pixel
    page.console = []
    page.on("console", lambda m: page.console.append(m.text))
    known = set(server.get_clients()) if server is not None else set()
    page.goto(url)
    page.wait_for_function("() => !document.body.innerText.includes('Connecting')", timeout=60_000)
    if server is None:
        return page, None
    client = wait_until(lambda: next((c for i, c in server.get_clients().items() if i not in known), None),
                        30, what="client")
    wait_until(lambda: client.camera.image_width > 0, 30, what="camera")
    return page, client


def hide_lines(client):
    """Count map colours only: the green reference trajectory and the current camera hidden for `client`."""
    for name in ("/trajectory", "/camera"):
        client.scene.add_frame(name, show_axes=False, visible=False)


def url_of(server):
    return f"http://127.0.0.1:{server.get_port()}/"


def text(page) -> str:
    return page.evaluate("() => document.body.innerText")


def slider_box(page):
    row = page.locator("label", has_text=re.compile(r"^Keyframe$")).first.locator("xpath=ancestor::*[.//input][1]")
    return row.locator("input.mantine-NumberInput-input")


def poll_render(client, predicate, what, timeout=60):
    last = {}

    def attempt():
        last["img"] = render(client, 60, 80)      # small: software WebGL renders take seconds
        return predicate(last["img"])
    try:
        return wait_until(attempt, timeout, interval=0.3, what=what) and last["img"]
    except AssertionError:
        img = last["img"]
        raise AssertionError(f"{what}: red={red(img)} green={green(img)} grey={grey(img)}")


PLOT_AXES = """() => Object.values((window.__viserTestpoints || {}).uplots || {}).map(t => ({
    x: t.chart.axes[0]._values || [], y: t.chart.axes[1]._values || [],
    legend: [...t.chart.root.querySelectorAll('.u-legend')].map(e => e.innerText)}))"""


def test_plots_show_values(browser, served, tmp_path):  # noqa: F811
    """Both axes have numbers (x: frame numbers, not "12:00:03am"; y: several distinct values, not one
    "0"), no legend reads "--", and the latest value of each plot is page text above it."""
    server, app = served
    page, _ = open_page(browser, url_of(server), server)
    try:
        charts = []

        def drawn():   # uPlot's axis values as drawn (its chart object, from viser's test point); a
            charts[:] = page.evaluate(PLOT_AXES)      # chart is first drawn 0 px wide, without x values
            return len(charts) == 4 and all(c["x"] and len(c["y"]) >= 2 for c in charts)
        wait_until(drawn, 30, interval=0.3, what="four plots with tick labels on both axes")
        for chart in charts:
            assert chart["x"] and all(re.fullmatch(r"\d+", v) for v in chart["x"]), charts
            assert len(set(chart["y"])) == len(chart["y"]), chart
            [float(v) for v in chart["y"]]                             # numbers, each of them
            assert not any("--" in legend for legend in chart["legend"]), chart
        body = text(page)
        for title in ("Tracking loss", "ATE up to each frame", "PSNR of the live render", "Seconds per frame"):
            assert re.search(re.escape(title) + r": [0-9.e-]+( cm| dB| s)? \(frame 4\)", body), (title, body)
        page.locator(".uplot-container").nth(1).scroll_into_view_if_needed()
        page.screenshot(path=str(tmp_path / "plots.png"))        # for a person to look at (pytest --basetemp)
    finally:
        page.close()


def test_keyframe_view_shows_the_map_and_stays_in_sync(browser, served):  # noqa: F811
    server, app = served
    page, client = open_page(browser, url_of(server), server)
    try:
        box = slider_box(page)
        box.fill("1")
        box.press("Enter")
        scrub = wait_until(lambda: app.scrubber.pages.get(client.client_id), 60, what="the page's scrubber")
        wait_until(lambda: scrub.position == 0, 60, what="slider at keyframe 1")
        # the label, the number box and the checkbox agree with the slider
        wait_until(lambda: "Keyframe 1 / 3 (frame #0)" in text(page), 30, what="label in the page")
        assert box.input_value() == "1" and not page.get_by_label("Follow latest").is_checked()
        # at the keyframe's pose (the first camera) the map shows, not the grey keyframe image planes
        wait_until(lambda: np.allclose(client.camera.position, 0.0, atol=1e-3), 60, what="camera at keyframe 1")
        img = poll_render(client, lambda im: red(im) > 80 and green(im) == 0, "map at keyframe 1")
        assert grey(img) < 0.05 * img.shape[0] * img.shape[1], grey(img)
        # a frustum click moves the Keyframes panel too
        scrub_frames = [kf.frame_index for kf in app.applied.keyframes]
        app.scrubber.on_frustum_click(type("Event", (), {"client": client})(), scrub_frames[2])
        wait_until(lambda: "Keyframe 3 / 3 (frame #4)" in text(page), 30, what="label after a frustum click")
        wait_until(lambda: box.input_value() == "3", 60, what="number box after a frustum click")
        wait_until(lambda: np.allclose(client.camera.position, [0.4, 0.0, 0.0], atol=1e-3), 60,
                   what="camera at keyframe 3")
    finally:
        page.close()


def test_a_new_page_follows_the_latest_map(browser, served):  # noqa: F811
    server, app = served
    first, client_a = open_page(browser, url_of(server), server)
    try:
        wait_until(lambda: client_a.client_id in app.scrubber.pages, 60, what="the page's scrubber")
        app.scrubber.go_to(client_a.client_id, 0)
        hide_lines(client_a)
        look(client_a, (0.5, 0.0, 0.8), (0.5, 0.0, 2.0))
        poll_render(client_a, lambda im: red(im) > 20 and green(im) == 0, "first page at keyframe 1")
        second, client_b = open_page(browser, url_of(server), server)
        try:
            # the box is created ticked and the slider at 1, then set to the newest keyframe: wait for both
            wait_until(lambda: second.get_by_label("Follow latest").is_checked()
                       and slider_box(second).input_value() == "3", 60, what="follow ticked, slider at keyframe 3")
            hide_lines(client_b)
            look(client_b, (0.5, 0.0, 0.8), (0.5, 0.0, 2.0))
            poll_render(client_b, lambda im: red(im) > 20 and green(im) > 20, "second page: the whole map")
            poll_render(client_a, lambda im: green(im) < 5, "first page still at keyframe 1")
        finally:
            second.close()
    finally:
        first.close()


def test_live_captions_and_texts_follow_the_state(browser, served):  # noqa: F811
    server, app = served
    page, _ = open_page(browser, url_of(server), server)
    try:
        wait_until(lambda: "Exports the finished run's map." in text(page), 30, what="export note")
        body = text(page)
        assert "SLAM keeps running" not in body and "ATE so far" not in body
        assert "finished" in body and "ATE:" in body
        # the live panel's words are page text, whole: no label drawn into the scaled images
        for words in ("Top: captured colour · captured depth · error (|render - captured| x3",
                      "Bottom: our render from the tracked pose", "silhouette (white = covered)"):
            assert words in body, words
        # every control has an explanation: the help covers the error tile and the run controls
        assert "Run controls (shared by every visitor)" in body
    finally:
        page.close()


def test_first_minute_explains_itself(browser):  # noqa: F811
    """Before frame 1 is done, the page shows the capture's first images and the compile note."""
    import threading

    import viser

    from app.viewer import build_viewer
    from app.worker import SlamWorker

    release = threading.Event()

    class SlowFirstFrame(FakePipeline):
        def step(self):
            release.wait(60)
            return super().step()

    pipe = SlowFirstFrame(total=2, per_frame=100)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    note = "compiling the CPU kernels: 3 / 18"        # what KernelCompile publishes on a first run
    compiled = threading.Event()

    def prepare(report):                              # the compile, until the page has shown its note
        report(note)
        compiled.wait(60)

    worker = SlamWorker(pipe, live_render=False, prepare=prepare)
    app = build_viewer(server, worker, render_backend="reference", preview_frame=pipe.frame(0))
    worker.start()
    try:
        page, _ = open_page(browser, url_of(server))
        wait_until(lambda: note in text(page), 60, what="the note")
        body = text(page)
        assert "Processing frame 1 / 2" in body and "Frame #0 as captured" in body
        compiled.set()
        release.set()
        wait_until(lambda: "Frame 2 / 2" in text(page), 30, what="the run goes on")
        assert "compiling" not in text(page)
        page.close()
    finally:
        compiled.set()
        release.set()
        worker.stop(join_timeout=10)
        app.close()
        server.stop()


def test_token_refuses_then_serves_and_view_only_page(browser):  # noqa: F811
    """Bound to 127.0.0.2 (an address of this machine other than 127.0.0.1): a token is needed."""
    import viser
    import websockets
    from websockets.sync.client import connect as connect_ws

    from app.commands.viewer import start_server
    from app.viewer import StaticSource, build_viewer
    from app.viewer.access import Access
    from helpers.maps import snapshot_of, two_walls

    access = Access.for_host("127.0.0.2", share="view")
    server = start_server("127.0.0.2", 0, access)
    app = build_viewer(server, StaticSource(snapshot_of(two_walls())), render_backend="reference", access=access)
    port = server.get_port()
    try:
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(f"http://127.0.0.2:{port}/", timeout=10)
        assert refused.value.code == 403
        with pytest.raises(websockets.exceptions.InvalidStatus):   # the websocket too
            connect_ws(f"ws://127.0.0.2:{port}", subprotocols=[f"viser-v{viser.__version__}"]).close()
        # the shared (view) URL: a page without run controls, export or refine
        view, _ = open_page(browser, access.url("127.0.0.2", port))
        wait_until(lambda: "view only" in text(view), 60, what="view-only note")
        body = text(view)
        assert "Keyframes" in body and "Export" not in body and "Refine" not in body
        assert view.get_by_role("button", name="Export and download").count() == 0
        view.close()
        # the control URL: the full page
        full, _ = open_page(browser, access.url("127.0.0.2", port, "control"))
        wait_until(lambda: "Export" in text(full) and "Refine" in text(full), 60, what="control panels")
        assert "view only" not in text(full)
        full.close()
        assert len(server.get_clients()) <= 2
    finally:
        app.close()
        server.stop()


def test_malformed_websocket_messages_are_ignored(served):
    import viser
    from websockets.sync.client import connect as connect_ws

    server, app = served
    with connect_ws(f"ws://127.0.0.1:{server.get_port()}", subprotocols=[f"viser-v{viser.__version__}"]) as ws:
        ws.send(b"\x00\x01not msgpack")
        ws.send("text frame")
        ws.recv(timeout=10)                              # still served after both
        assert ws.ping().wait(10)                        # and still read: the server answers a ping
        assert ws.state.name == "OPEN"
