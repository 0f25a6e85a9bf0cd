"""`nerfcapture://`: live RGB-D frames from the NeRFCapture iPhone app, recorded as they arrive.

    stream = NeRFCaptureStream("run/capture", idle_timeout=30)
    while (frame := stream.next_frame()) is not None: ...   # the newest frame each time
    stream.close()

A receiver thread takes every message off DDS (`nerfcapture_dds.DDSReceiver`), writes it to the
capture folder (`nerfcapture_record.CaptureRecorder`: SplaTAM's layout, which `--input` reads
back) and keeps only the newest one for SLAM. `next_frame()` hands that one over; frames SLAM
never got (replaced by a newer one while it was busy, or arriving after it stopped) are counted
in `dropped`. So SLAM runs on the freshest frame, and `splatam run --input <capture folder>`
redoes the run offline on every frame.

Frames come at the colour resolution with depth nearest-upsampled to it, built from the very
bytes written to the folder: the offline reader yields identical frames. Intrinsics are the
first frame's (fl_x fl_y cx cy at the colour resolution); poses are converted from ARKit to
OpenCV camera axes, in ARKit's gravity-up world, as the offline reader does.

The stream ends after `max_frames` received, on `stop()`/`close()` (Ctrl-C), or after
`idle_timeout` seconds without a frame (None: never). It is a LiveSource (source.py): the
Pipeline pulls with `next_frame()` instead of indexing, `received` / `dropped` count the frames,
and `source[i]` reads received frame i back from the folder.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from ..camera import c2w_opengl_to_opencv
from ..errors import InputError
from ..frame import Frame
from ..intrinsics import Intrinsics
from .camera_files import make_intrinsics
from .images import color_to_float, raw_depth_to_metres, read_color, read_depth_png
from .nerfcapture_dds import DOMAIN_ID, TOPIC, dds_config_label, decode
from .nerfcapture_record import UNITS_PER_METRE, CaptureRecorder
from .source import LiveSource

URL = "nerfcapture://"
POLL_S = 0.2


def waiting_message() -> str:
    return (f"waiting for NeRFCapture frames (DDS domain {DOMAIN_ID}, topic {TOPIC}; {dds_config_label()}): "
            "in the app choose Online mode, wait for '1 Connection(s)', then tap Send")


class NeRFCaptureStream(LiveSource):
    format_name = "nerfcapture-stream"
    registered_by = "the phone app: ARKit delivers depth registered to the colour image"

    def __init__(self, capture_dir, *, idle_timeout: float | None = 30.0, max_frames: int | None = None,
                 receiver=None, url: str = URL):
        if url != URL:
            raise InputError(f"{url}: expected exactly {URL} (the NeRFCapture app on DDS domain {DOMAIN_ID})")
        self.path = Path(capture_dir)
        self.idle_timeout = idle_timeout or None
        self.max_frames = max_frames
        self._recorder = CaptureRecorder(self.path)
        if receiver is None:
            from .nerfcapture_dds import DDSReceiver
            receiver = DDSReceiver()
        self._receiver = receiver
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._ended = threading.Event()
        self.end_reason: str | None = None
        self.delivered = 0
        self.rejected = 0
        self.last_rejection: str | None = None
        self._pending: tuple[int, np.ndarray, np.ndarray] | None = None  # (index, rgb, depth units)
        self._meta: list[tuple[float, np.ndarray]] = []                   # (timestamp, c2w OpenCV) per frame
        self._intr: Intrinsics | None = None
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._receive, name="nerfcapture-receiver", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ receiver thread
    def _receive(self) -> None:
        last = time.monotonic()
        try:
            while not self._stop.is_set():
                for msg in self._receiver.poll(POLL_S):
                    if self._accept(msg):
                        last = time.monotonic()
                    if self.max_frames and len(self._meta) >= self.max_frames:
                        return self._end(f"{self.max_frames} frames received")
                if self.idle_timeout and time.monotonic() - last > self.idle_timeout:
                    return self._end(f"no frame for {self.idle_timeout:g} s")
            self._end("stopped")
        except BaseException as e:  # a full disk, a DDS failure: next_frame() reports it
            self.error = e
            self._end(f"failed: {e}")
        finally:
            self._receiver.close()

    def _accept(self, msg) -> bool:
        try:
            f = decode(msg)
            index, units = self._recorder.add(f)
        except ValueError as e:
            self.rejected += 1
            self.last_rejection = str(e)
            return False
        with self._cond:
            if self._intr is None:
                self._intr = make_intrinsics(f.fl_x, f.fl_y, f.cx, f.cy, f.size[0], f.size[1], str(self.path))
            self._meta.append((f.timestamp, c2w_opengl_to_opencv(f.c2w_arkit)))
            self._pending = (index, f.rgb, units)
            self._cond.notify_all()
        return True

    def _end(self, reason: str) -> None:
        with self._cond:
            self.end_reason = self.end_reason or reason
            self._ended.set()
            self._cond.notify_all()

    # ------------------------------------------------------------------ LiveSource
    def next_frame(self, timeout: float | None = None) -> Frame | None:
        """The newest frame not yet handed out; None when the stream has ended (or after
        `timeout` seconds without one). Frames SLAM skipped stay in the capture folder."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while self._pending is None and not self._ended.is_set():
                if deadline is not None and time.monotonic() >= deadline:
                    return None
                self._cond.wait(POLL_S)
            if self.error is not None:
                raise InputError(f"{self.path}: the NeRFCapture stream failed ({self.error})")
            if self._pending is None or self._stop.is_set():   # stopped (Ctrl-C): no further frame
                return None
            index, rgb, units = self._pending
            self._pending = None
            self.delivered += 1
        depth, _ = raw_depth_to_metres(units, UNITS_PER_METRE, str(self.path))
        return self._frame(index, color_to_float(rgb, str(self.path), bgr=False), depth)

    def wait_ended(self, timeout: float) -> bool:
        return self._ended.wait(timeout)

    def stop(self) -> None:
        """Ask the stream to end (safe from a signal handler: sets a flag, never blocks)."""
        self._stop.set()

    def close(self) -> None:
        self.stop()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(10.0)

    def stats(self) -> dict:
        return dict(super().stats(), rejected=self.rejected, stream_end=self.end_reason, capture=str(self.path))

    def no_frame_message(self) -> str:
        why = f"{self.rejected} frames rejected, last: {self.last_rejection}; " if self.rejected else ""
        waited = f"in {self.idle_timeout:g} s" if self.end_reason.startswith("no frame") else f"({self.end_reason})"
        return (f"nerfcapture://: no usable frame from the NeRFCapture app {waited}; {why}check that the phone is "
                "on the same Wi-Fi as this machine, the app is in Online mode and shows a connection "
                f"(tap Send to send a frame), and the DDS configuration ({dds_config_label()})")

    # ------------------------------------------------------------------ FrameSource
    def __len__(self) -> int:
        return len(self._meta)

    @property
    def intrinsics(self) -> Intrinsics:
        """The first frame's; waits for it (InputError saying what to check if the stream ends first)."""
        with self._cond:
            while self._intr is None and not self._ended.is_set():
                self._cond.wait(POLL_S)
            if self._intr is None:
                raise InputError(self.no_frame_message())
            return self._intr

    @property
    def timestamps(self) -> np.ndarray:
        return np.array([t for t, _ in self._meta], dtype=np.float64)

    @property
    def has_reference_poses(self) -> bool:
        return bool(self._meta)

    def reference_c2w(self) -> np.ndarray | None:
        return np.stack([T for _, T in self._meta]) if self._meta else None

    def __getitem__(self, i: int) -> Frame:
        if not 0 <= i < len(self._meta):
            raise IndexError(f"frame {i} not received (the stream has {len(self._meta)} frames)")
        depth, _ = read_depth_png(self.path / f"depth/{i}.png", UNITS_PER_METRE)
        return self._frame(i, read_color(self.path / f"rgb/{i}.png"), depth)

    def _frame(self, i: int, color: np.ndarray, depth: np.ndarray) -> Frame:
        t, c2w = self._meta[i]
        return Frame(i, t, color, depth, self._intr, c2w.copy())

    def describe(self) -> str:
        return f"NeRFCapture stream (DDS domain {DOMAIN_ID}, topic {TOPIC}) recorded to {self.path}"
