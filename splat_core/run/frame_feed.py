"""The frames a run processes: opening the input, choosing frame indices, skipping bad frames.

    feed = FrameFeed(open_input("capture/"), intrinsics, config, max_frames=100, stride=2)
    frame = feed.next(started=True)     # the next usable frame at the working resolution, or None

A capture is read by index (`indices`: every stride-th frame, at most max_frames); a LiveSource
(io/source.py, e.g. nerfcapture://) is pulled with next_frame() and `indices` grows as frames
arrive; a capture played back in real time (io/playback.py) is pulled by index (next_index()). A bad frame is skipped with a one-line warning; a capture whose first
MAX_LEADING_BAD_FRAMES frames are all unusable is refused as a whole.

A capture read by index is read one frame ahead in a thread of its own (`Prefetch`): the next
frame is decoded (the synthetic scene: ray-cast) while the current one is tracked, instead of in
the tracker's thread between frames (on 2 loaded cores the synthetic scene took 0.14 s a frame to
make, 7-Scenes and SUN3D 14-37 ms to read: benchmarks/frame_read_cost.py, docs/benchmarks.md "Live rate"). Every read of the source goes
through one lock, so a source is never read by two threads at once.
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ..camera import Intrinsics
from ..config import Config
from ..errors import InputError
from ..frame import Frame, resize_frame
from ..io.source import FrameSource, LiveSource

MAX_LEADING_BAD_FRAMES = 10


def open_input(path=None, format: str | None = None, **options) -> FrameSource:
    """A capture (folder or .r3d/.zip, format detected), the live `nerfcapture://` stream (options:
    capture_dir, idle_timeout) or, with no path, the synthetic demo scene."""
    if isinstance(path, str) and path.startswith("nerfcapture://"):
        from ..io.nerfcapture_stream import NeRFCaptureStream
        return NeRFCaptureStream(url=path, **options)
    if path is None:
        from ..synthetic import SyntheticSource
        return SyntheticSource(**options)
    from ..io import open_capture
    return open_capture(path, format=format, **options)


def resolve_device(device: str) -> torch.device:
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA device is available to torch")
    if device not in ("cpu", "cuda"):
        raise InputError(f"--device {device}: expected auto, cpu or cuda")
    return torch.device(device)


def check_frame(frame: Frame, where: str) -> None:
    if frame.color.shape[:2] != frame.depth.shape:
        raise InputError(f"{where}: colour {frame.color.shape[:2]} and depth {frame.depth.shape} sizes differ")
    if not np.all(np.isfinite(frame.depth)):
        raise InputError(f"{where}: depth has NaN or inf values")
    if not (frame.depth > 0).any():
        raise InputError(f"{where}: no valid depth in this frame")


def prepare_frame(source: FrameSource, i: int, intrinsics: Intrinsics, max_depth: float | None,
                  raw: Frame | None = None) -> Frame:
    """Capture frame i (or `raw`, that frame as received) at `intrinsics`' resolution, depth cut at
    max_depth; InputError naming the file when it is unusable."""
    frame = source.frame_at_size(i, intrinsics.width, intrinsics.height) if raw is None else raw
    name = source._name(i, "depth") if hasattr(source, "_name") else f"{getattr(source, 'path', 'input')} frame {i}"
    check_frame(frame, name)
    frame = resize_frame(frame, intrinsics.width, intrinsics.height)
    if max_depth:
        frame.depth = np.where(frame.depth <= max_depth, frame.depth, 0).astype(np.float32)
    return frame


def input_record(source: FrameSource) -> dict | None:
    """Where a run's frames came from, so `splatam refine` can re-read them (a live stream: the capture
    folder it was recorded to, whose format is detected); None for the synthetic scene."""
    if getattr(source, "path", None) is None:
        return None
    live = isinstance(source, LiveSource) and not hasattr(source, "next_index")   # a playback: its capture's
    return dict(path=str(Path(source.path).resolve()), format=None if live else source.format_name)


def warn(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr, flush=True)


class Prefetch:
    """One frame read ahead in a thread of its own: `start(i, read)` runs read(i) in the background;
    `take(i)` returns its frame (or raises its exception) when the read was of frame i, else None."""

    def __init__(self):
        self.index: int | None = None
        self._thread: threading.Thread | None = None
        self._outcome: list = []        # [frame, exception] of the read in flight, once it has ended

    def start(self, i: int, read: Callable[[int], Frame]) -> None:
        outcome: list = []              # this read's own (a cancelled read's thread writes only its own)

        def run():
            try:
                outcome.extend((read(i), None))
            except BaseException as e:       # handed to the reader's thread by take()
                outcome.extend((None, e))
        self.index, self._outcome = i, outcome
        self._thread = threading.Thread(target=run, name="frame-prefetch", daemon=True)
        self._thread.start()

    def take(self, i: int) -> Frame | None:
        thread, outcome, index = self._thread, self._outcome, self.index
        self.cancel()
        if thread is None or index != i:
            return None
        thread.join()
        frame, error = outcome
        if error is not None:
            raise error
        return frame

    def cancel(self) -> None:
        """Forget a read in flight (its thread finishes on its own; the source's lock orders it)."""
        self._thread, self.index, self._outcome = None, None, []


class FrameFeed:
    def __init__(self, source: FrameSource, intrinsics: Intrinsics, config: Config, *,
                 max_frames: int | None = None, stride: int = 1):
        self.source, self.intrinsics, self.max_depth = source, intrinsics, config.max_depth
        self.streaming = isinstance(source, LiveSource)
        if self.streaming:
            self.indices: list[int] = []
            self.total = max_frames or None
        else:
            self.indices = list(range(0, len(source), stride))[: max_frames if max_frames else None]
            if not self.indices:
                raise InputError(f"{self.where}: no frames to process")
            self.total = len(self.indices)
        self.cursor = 0                        # next position in `indices` (frames read, skipped ones included)
        self._read_lock = threading.Lock()      # every read of the source (the prefetch thread's too)
        self._ahead = None if self.streaming else Prefetch()
        self.skipped: list[dict] = []          # bad frames: source_index and the one-line reason
        self.warn = warn

    @property
    def where(self) -> str:
        return str(getattr(self.source, "path", "input"))

    def frame_at(self, i: int, raw: Frame | None = None) -> Frame:
        """Capture frame i (or `raw`, that frame as received) at the working resolution."""
        if raw is not None:
            return prepare_frame(self.source, i, self.intrinsics, self.max_depth, raw)
        with self._read_lock:
            return prepare_frame(self.source, i, self.intrinsics, self.max_depth)

    def next(self, started: bool, check: Callable[[Frame, int], None] | None = None) -> Frame | None:
        """The next usable frame; bad ones (and those `check` refuses with InputError) are skipped
        with a one-line warning. None at the end.

        Before the first usable frame (`started` False) the warnings wait: a capture refused as a
        whole gets its one error line and no list of warnings."""
        held = []
        while self.total is None or self.cursor < self.total:
            pulled = None
            if self.streaming and hasattr(self.source, "next_index"):   # a capture played back (io/playback.py)
                if (index := self.source.next_index()) is None:
                    break
                self.indices.append(index)
            elif self.streaming:
                if (pulled := self.source.next_frame()) is None:   # the stream ended
                    break
                self.indices.append(pulled.index)
            i = int(self.indices[self.cursor])
            self.cursor += 1
            try:
                frame = self._ahead.take(i) if self._ahead is not None else None
                if frame is None:
                    frame = self.frame_at(i, pulled)
                if self._ahead is not None and self.cursor < self.total:
                    self._ahead.start(int(self.indices[self.cursor]), self.frame_at)
                if check is not None:
                    check(frame, i)
                for message in held:
                    self.warn(message)
                return frame
            except InputError as e:
                self.skipped.append(dict(source_index=i, reason=str(e)))
                if started:
                    self.warn(f"skipped {e}")
                else:
                    held.append(f"skipped {e}")
                if not started and len(self.skipped) >= MAX_LEADING_BAD_FRAMES:
                    raise InputError(f"{self.where}: the first {len(self.skipped)} "
                                     f"frames are unusable (last: {e})") from None
        if not started and self.skipped:
            raise InputError(f"{self.where}: no usable frame "
                             f"({len(self.skipped)} skipped; last: {self.skipped[-1]['reason']})")
        return None

    def state(self) -> dict:
        return dict(indices=self.indices, total=self.total, cursor=self.cursor, skipped=self.skipped)

    def load_state(self, meta: dict, frames_done: int) -> None:
        self.cursor = int(meta.get("cursor", frames_done))
        self.skipped = list(meta.get("skipped", []))
