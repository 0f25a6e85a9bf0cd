"""LivePreview: the live panel's render of the map at the tracked pose, made in its own thread.

    preview = LivePreview(render, interval_s=1.0, duty=0.25)   # render(*what) -> LiveView or None
    preview.offer(*what)                      # the SLAM thread, after every frame: never blocks
    preview.latest()                          # the newest LiveView (None before the first)
    preview.flush()                           # render what is offered now and wait for it (pause, end)
    preview.close()

Why a thread: the render (the whole map at up to 320 pixels wide then; the panel's 200 now, on
the CPU) took the SLAM thread about as long as tracking a frame with the `live` preset, so the
viewer ran SLAM at about a third of its headless rate (docs/benchmarks.md, Viewer). Here the SLAM
thread only hands over the frame; the preview renders the newest frame offered when it is due and
drops the ones offered meanwhile, so image and render still belong to the same frame.

When due: at most every `interval_s`, and after a render that took r seconds not before r / duty
seconds have passed since it started, so the preview takes at most `duty` of one core however
slow the machine. The render reads a published map version (immutable), never the tensors the
mapper is stepping.
"""

from __future__ import annotations

import logging
import threading
import time
import traceback

log = logging.getLogger(__name__)


class LivePreview:
    def __init__(self, render, interval_s: float = 1.0, duty: float = 0.25):
        if not 0 < duty <= 1:
            raise ValueError(f"duty must be in (0, 1], got {duty}")
        self.render = render
        self.interval_s = float(interval_s)
        self.duty = float(duty)
        self.renders = 0                      # renders made (tests, the benchmark)
        self._cond = threading.Condition()
        self._offer = None                    # the newest offer's arguments, not yet rendered
        self._offered = self._done = 0        # offers made / the offer number the latest render answered
        self._latest = None
        self._not_before = 0.0                # monotonic time the next render may start
        self._flushes = 0                     # flush() calls waiting: render at once
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="live-preview", daemon=True)
        self._thread.start()

    def offer(self, *what) -> None:
        """Hand over the newest frame (replacing an older one not yet rendered)."""
        with self._cond:
            self._offer = what
            self._offered += 1
            self._cond.notify_all()

    def latest(self):
        return self._latest

    def flush(self, timeout: float | None = None) -> None:
        """Render the newest offer now, whatever the pacing, and return once it is shown (or the
        preview is closed). For a pause and the run's end, where the panel must show the last frame."""
        with self._cond:
            self._flushes += 1
            self._cond.notify_all()
            target = self._offered
            try:
                self._cond.wait_for(lambda: self._done >= target or self._closed, timeout)
            finally:
                self._flushes -= 1

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._closed:
                    wait = self._not_before - time.monotonic()
                    if self._offer is not None and (wait <= 0 or self._flushes):
                        break
                    self._cond.wait(wait if self._offer is not None else None)
                if self._closed:
                    return
                what, number = self._offer, self._offered
                self._offer = None
            start = time.monotonic()
            try:
                view = self.render(*what)
            except Exception:  # a failed preview must never stop SLAM or the viewer
                log.warning("live render failed:\n%s", traceback.format_exc())
                view = None
            took = time.monotonic() - start
            with self._cond:
                if view is not None:
                    self._latest = view
                    self.renders += 1
                self._done = number
                self._not_before = start + max(self.interval_s, took / self.duty)
                self._cond.notify_all()
