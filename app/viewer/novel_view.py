"""Our own renderer in the viewer: one render thread with latest-request slots.

`RenderService` runs render jobs on one thread. Each slot (a browser client's novel view, the
keyframe comparison) holds only its latest request, so a fast camera drag never queues stale
work. `NovelView` is the per-client novel-view mode: while it is on, the client's WebGL splats
are hidden by shadowing `/map` for that client only (docs/viewer-notes.md §1.8), and our render of the map
from the browser camera is sent as that client's background image: low resolution while the
camera moves, full resolution once it has been still for a moment (the nerfview pattern).
"""

from __future__ import annotations

import logging
import threading
import time
import traceback

import numpy as np

from splat_core.camera import Intrinsics, invert_pose, pose_matrix, quat_to_rotmat_np

from ..images import colorize_depth, colorize_silhouette, to_uint8

log = logging.getLogger(__name__)

MODES = {  # dropdown label -> render channel (None = viser's WebGL splats)
    "WebGL splats (fast)": None,
    "Our render: colour": "color",
    "Our render: depth": "depth",
    "Our render: silhouette": "silhouette",
}


class RenderService(threading.Thread):
    """Runs submitted jobs on one thread; a slot keeps only its latest job."""

    def __init__(self, tick_interval_s: float = 0.1):
        super().__init__(name="viewer-render", daemon=True)
        self._cond = threading.Condition()
        self._slots: dict = {}
        self._order: list = []
        self._tickers: list = []
        self._stopped = False
        self.tick_interval_s = tick_interval_s
        self.jobs_done = 0

    def submit(self, slot, job) -> None:
        with self._cond:
            self._slots[slot] = job
            if slot in self._order:
                self._order.remove(slot)
            self._order.append(slot)
            self._cond.notify_all()

    def cancel(self, slot) -> None:
        with self._cond:
            self._slots.pop(slot, None)
            if slot in self._order:
                self._order.remove(slot)

    def add_ticker(self, fn) -> None:
        """`fn()` is called on the render thread about every tick_interval_s (to schedule work)."""
        with self._cond:
            self._tickers.append(fn)

    def remove_ticker(self, fn) -> None:
        with self._cond:
            if fn in self._tickers:
                self._tickers.remove(fn)

    def stop(self) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify_all()

    def run(self) -> None:
        while True:
            with self._cond:
                if not self._order and not self._stopped:
                    self._cond.wait(self.tick_interval_s)
                if self._stopped:
                    return
                tickers = list(self._tickers)
            for fn in tickers:
                self._safe(fn)
            with self._cond:
                if not self._order:
                    continue
                slot = self._order.pop(0)
                job = self._slots.pop(slot)
            self._safe(job)
            self.jobs_done += 1

    @staticmethod
    def _safe(fn) -> None:
        try:
            fn()
        except Exception:
            log.warning("viewer render job failed:\n%s", traceback.format_exc())


def browser_camera(client, max_width: int) -> tuple[Intrinsics, np.ndarray]:
    """Intrinsics (square pixels, at most `max_width` wide) and w2c of a client's camera."""
    cam = client.camera
    W0, H0 = max(1, int(cam.image_width)), max(1, int(cam.image_height))
    W = min(W0, max_width)
    H = max(1, int(round(H0 * W / W0)))
    intr = Intrinsics.from_fov(float(cam.fov), W, H)
    c2w = pose_matrix(quat_to_rotmat_np(np.asarray(cam.wxyz)), np.asarray(cam.position))
    return intr, invert_pose(c2w)


def channel_image(out, channel: str, depth_max: float | None = None) -> np.ndarray:
    """A Render's colour / depth / silhouette as uint8 RGB."""
    color, depth, alpha = (t.detach().cpu().numpy() for t in out)
    if channel == "depth":
        return colorize_depth(depth, depth_max)
    if channel == "silhouette":
        return colorize_silhouette(alpha)
    return to_uint8(color)


class NovelView:
    """The novel-view mode of one browser client."""

    def __init__(self, client, service: RenderService, render_fn, *, full_width: int = 640,
                 low_width: int = 160, still_after_s: float = 0.3):
        self.client = client
        self.service = service
        self.render_fn = render_fn           # render_fn(intrinsics, w2c) -> Render or None
        self.full_width = full_width
        self.low_width = low_width
        self.still_after_s = still_after_s
        self.channel: str | None = None
        self.frames_sent = 0
        self.last_width = 0
        self._shadow = None
        self._last_move = 0.0
        self._full_done = True
        self._lock = threading.Lock()
        client.camera.on_update(lambda _cam: self.on_move())
        service.add_ticker(self._tick)

    def set_mode(self, channel: str | None) -> None:
        with self._lock:
            self.channel = channel
            if channel is None:
                if self._shadow is not None:
                    self._shadow.remove()
                    self._shadow = None
                self.service.cancel(self)
                self.client.scene.set_background_image(None)
                return
            if self._shadow is None:  # hide the WebGL map for this client only
                self._shadow = self.client.scene.add_frame("/map", show_axes=False, visible=False)
            self._full_done = False
            self._last_move = 0.0
        self.service.submit(self, lambda: self._render(self.full_width))

    def on_move(self) -> None:
        if self.channel is None:
            return
        self._last_move = time.monotonic()
        self._full_done = False
        self.service.submit(self, lambda: self._render(self.low_width))

    def refresh(self) -> None:
        """The map changed: re-render at full resolution."""
        if self.channel is not None:
            self._full_done = False
            self._last_move = 0.0

    def _tick(self) -> None:
        if self.channel is not None and not self._full_done and \
                time.monotonic() - self._last_move >= self.still_after_s:
            self._full_done = True
            self.service.submit(self, lambda: self._render(self.full_width))

    def _render(self, width: int) -> None:
        channel = self.channel
        if channel is None:
            return
        intr, w2c = browser_camera(self.client, width)
        out = self.render_fn(intr, w2c)
        if out is None or self.channel != channel:
            return
        image = channel_image(out, channel)
        quality = 85 if width >= self.full_width else 50
        self.client.scene.set_background_image(image, format="jpeg", jpeg_quality=quality)
        self.frames_sent += 1
        self.last_width = image.shape[1]

    def close(self) -> None:
        self.service.remove_ticker(self._tick)
        self.service.cancel(self)
