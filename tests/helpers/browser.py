"""Driving the viewer's page in Chromium: connect a page, place the camera, read its render, count colours."""

from __future__ import annotations

import numpy as np

from app.viewer.page_camera import place

from .viewer import wait_until


def connect(browser, server):
    """A page on the server, connected; returns (page, client, external requests list)."""
    page = browser.new_page(viewport={"width": 1000, "height": 700}, accept_downloads=True)
    external, errors = [], []
    page.on("request", lambda r: external.append(r.url) if not r.url.startswith(
        ("http://127.0.0.1", "ws://127.0.0.1", "data:", "blob:")) else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"http://127.0.0.1:{server.get_port()}/")
    page.wait_for_function("() => !document.body.innerText.includes('Connecting')", timeout=60_000)
    client = wait_until(lambda: next(iter(server.get_clients().values()), None), 60, what="client")
    wait_until(lambda: client.camera.image_width > 0, 30, what="camera")
    # the page reports its own start-up pose first and applies the server's initial camera after
    # it: wait for that, or a camera a test sets now may be replaced by the initial one
    wait_until(lambda: np.allclose(client.camera.position, server.initial_camera.position, atol=1e-3), 30,
               what="the page at the server's initial camera")
    page.external_requests, page.errors = external, errors
    return page, client


def look(client, position, look_at):
    """Set the page's camera and wait until the page reports it."""
    place(client, position, look_at)
    wait_until(lambda: np.allclose(client.camera.position, position, atol=1e-3)
               and np.allclose(client.camera.look_at, look_at, atol=1e-3), 30, what=f"the page's camera at {position}")


def render(client, h=150, w=200):
    return np.asarray(client.get_render(h, w, timeout=60), np.int32)


def count(img, lo, hi):
    lo, hi = np.asarray(lo), np.asarray(hi)
    rgb = img[..., :3]
    return int(np.all((rgb >= lo) & (rgb <= hi), axis=-1).sum())


def red(img):
    return count(img, (150, 0, 0), (255, 90, 90))


def green(img):
    return count(img, (0, 140, 0), (110, 255, 110))


def poll_render(client, predicate, timeout=60, what="render"):
    last = {}

    def attempt():
        last["img"] = render(client)
        return predicate(last["img"])
    try:
        wait_until(attempt, timeout, interval=0.3, what=what)
    except AssertionError:
        import cv2
        cv2.imwrite(f"/tmp/viewer_test_{what.replace(' ', '_')}.png", last["img"][..., :3][..., ::-1].astype(np.uint8))
        raise AssertionError(f"{what}: last render red={red(last['img'])} green={green(last['img'])}")
    return last["img"]


def frames_shown(page) -> int:
    row = page.locator("label", has_text="Frames processed").first.locator("xpath=ancestor::*[.//input][1]")
    return int(row.locator("input").first.input_value() or 0)
