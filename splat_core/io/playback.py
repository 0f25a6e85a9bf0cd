"""`--realtime [FPS]`: a capture played back at its own frame rate, as a live stream would arrive.

    source = RealtimePlayback(open_capture("capture/"))            # the capture's own rate (timestamps)
    source = RealtimePlayback(open_capture("capture/"), fps=15)     # every frame 1/15 s after the last
    frame = source.next_frame()     # the newest frame that has "arrived"; those it replaced are dropped

It wraps any FrameSource (every file format, the synthetic scene) and is a LiveSource (source.py):
SLAM gets the newest frame that has arrived, never a queue; `received` counts the frames arrived,
`dropped` those never handed out. Frame i arrives at `arrival[i]` seconds after frame 0: its
timestamp minus frame 0's, or i / fps with `fps` given, or i / 30 when the timestamps are missing
or degenerate (not finite, not increasing, or all equal).

The clock starts when SLAM asks for the second frame: frame 0 is handed over at once, and only
once it has been tracked and mapped (the Pipeline drains the engine after its first frame) does
playback begin, at frame 0's time; the first frame's mapping (many iterations) costs no frames.
A consumer faster than the capture waits (`sleep`) for the next frame to arrive. The capture's
last frame is always handed over (the consumer waits for it if need be), and the next call after
it ends the playback. `clock` and `sleep` are injectable: tests drive a fake clock that `sleep`
advances, and nothing waits on wall time.
"""

from __future__ import annotations

import bisect
import time
from typing import Callable

import numpy as np

from ..errors import InputError
from ..frame import Frame
from .source import FrameSource, LiveSource

DEFAULT_FPS = 30.0      # when the capture's timestamps cannot give its rate


def arrival_times(timestamps, n: int, fps: float | None = None) -> tuple[np.ndarray, float | None]:
    """Seconds after frame 0 at which each of n frames arrives, and the rate they came from (None:
    the timestamps, irregular)."""
    if fps is not None:
        if not fps > 0:
            raise InputError(f"--realtime {fps:g}: expected a positive frame rate")
        return np.arange(n, dtype=np.float64) / fps, float(fps)
    t = np.asarray(timestamps if timestamps is not None else [], dtype=np.float64).ravel()
    if n > 1 and len(t) >= n and np.all(np.isfinite(t[:n])) and np.all(np.diff(t[:n]) >= 0) and t[n - 1] > t[0]:
        return t[:n] - t[0], None
    return np.arange(n, dtype=np.float64) / DEFAULT_FPS, DEFAULT_FPS


class RealtimePlayback(LiveSource):
    def __init__(self, inner: FrameSource, fps: float | None = None, *, max_frames: int | None = None,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep):
        if getattr(inner, "live", False):
            raise InputError("--realtime plays a capture back; a live stream already arrives in real time")
        self.inner = inner
        self.count = min(len(inner), max_frames) if max_frames else len(inner)
        if self.count < 1:
            raise InputError(f"{inner.describe()}: no frames to play back")
        try:
            stamps = inner.timestamps
        except (InputError, OSError, ValueError):
            stamps = None
        self.arrival, self.fps = arrival_times(stamps, self.count, fps)
        self.clock, self.sleep = clock, sleep
        self.format_name, self.path, self.registered = inner.format_name, inner.path, inner.registered
        self.registered_by = inner.registered_by
        self.delivered = 0
        self._arrived = 0           # frames arrived so far (updated when SLAM asks for a frame)
        self._last = -1             # newest frame handed out
        self._start: float | None = None
        self._stopped = False

    # ------------------------------------------------------------------ LiveSource
    def next_frame(self, timeout: float | None = None) -> Frame | None:
        """The newest frame arrived and not yet handed out (waiting for the next one to arrive if
        none is); None once the capture's last frame has been handed out, after stop(), or after
        `timeout` seconds without a frame."""
        index = self.next_index(timeout)
        return None if index is None else self.inner[index]

    def next_index(self, timeout: float | None = None) -> int | None:
        """next_frame's frame index, the frame not read (the FrameFeed reads it at its working size:
        FrameSource.frame_at_size)."""
        if self._stopped or self._last >= self.count - 1:
            return None
        if self._last < 0:                       # frame 0: at once; the clock is not running yet
            index = 0
        else:
            if self._start is None:              # SLAM asks for the second frame: the first is mapped
                self._start = self.clock() - self.arrival[0]
            wait = self.arrival[self._last + 1] - self._elapsed()
            if wait > 0:
                if timeout is not None and wait > timeout:
                    self.sleep(timeout)
                    self._arrived = max(self._arrived, self._count_arrived())
                    return None
                self.sleep(wait)
            index = max(self._last + 1, self._count_arrived() - 1)
        self._arrived = max(self._arrived, index + 1)
        self._last = index
        self.delivered += 1
        return index

    def _elapsed(self) -> float:
        return self.clock() - self._start

    def _count_arrived(self) -> int:
        return min(self.count, bisect.bisect_right(self.arrival, self._elapsed()))

    def stop(self) -> None:
        self._stopped = True

    def close(self) -> None:
        self.stop()
        self.inner.close()

    def stats(self) -> dict:
        rate = "the capture's timestamps" if self.fps is None else f"{self.fps:g} frames/s"
        return dict(super().stats(), realtime=rate)

    def end_message(self) -> str:
        return (f"real-time playback ({self.stats()['realtime']}): {self.received} frames arrived, "
                f"{self.delivered} processed, {self.dropped} dropped")

    # ------------------------------------------------------------------ FrameSource (the capture's)
    def __len__(self) -> int:
        return self._arrived

    def __getitem__(self, i: int) -> Frame:
        return self.inner[i]

    @property
    def intrinsics(self):
        return self.inner.intrinsics

    @property
    def timestamps(self) -> np.ndarray:
        return np.asarray(self.inner.timestamps)[: self._arrived]

    @property
    def has_reference_poses(self) -> bool:
        return self.inner.has_reference_poses

    def reference_c2w(self) -> np.ndarray | None:
        ref = self.inner.reference_c2w()
        return None if ref is None else ref[: self._arrived]

    def frame_at_size(self, i: int, width: int, height: int) -> Frame:
        return self.inner.frame_at_size(i, width, height)

    def raw_pair(self, i: int):
        return self.inner.raw_pair(i)

    def _name(self, i: int, kind: str) -> str:
        name = getattr(self.inner, "_name", None)
        return name(i, kind) if name is not None else f"{self.path or 'input'} frame {i}"

    def describe(self) -> str:
        rate = "its own rate" if self.fps is None else f"{self.fps:g} frames/s"
        return f"{self.inner.describe()}, played back in real time at {rate} (the newest frame to SLAM)"
