"""The frame feed reads a capture one frame ahead in a thread of its own (splat_core/run/frame_feed.py,
`Prefetch`): the same frames in the same order, bad frames skipped as before, the source never read
by two threads at once. Nothing here waits on wall time: the tests hold reads with events."""

from __future__ import annotations

import threading

import numpy as np

from splat_core.config import load_config
from splat_core.errors import InputError
from splat_core.frame import Frame
from splat_core.intrinsics import Intrinsics
from splat_core.io.source import FrameSource
from splat_core.run.frame_feed import FrameFeed


class Recorded(FrameSource):
    """n tiny frames whose colour is their index; records which thread read each frame and how many
    reads ran at once; `bad` frames have no valid depth; a read of frame `hold` waits for `release`."""
    format_name = "test"

    def __init__(self, n: int, bad=(), hold: int | None = None):
        self.n, self.bad, self.hold = n, set(bad), hold
        self.readers: dict[int, list[str]] = {}
        self.inside = self.most_inside = 0
        self.count_lock = threading.Lock()
        self.entered, self.release = threading.Event(), threading.Event()

    def __len__(self):
        return self.n

    def __getitem__(self, i):
        with self.count_lock:
            self.inside += 1
            self.most_inside = max(self.most_inside, self.inside)
        try:
            if i == self.hold:
                self.entered.set()
                self.release.wait()
            self.readers.setdefault(i, []).append(threading.current_thread().name)
            depth = np.zeros((4, 4), np.float32) if i in self.bad else np.ones((4, 4), np.float32)
            return Frame(i, i / 30.0, np.full((4, 4, 3), i / 100.0, np.float32), depth, self.intrinsics, np.eye(4))
        finally:
            with self.count_lock:
                self.inside -= 1

    @property
    def intrinsics(self):
        return Intrinsics(4.0, 4.0, 2.0, 2.0, 4, 4)

    @property
    def timestamps(self):
        return np.arange(self.n) / 30.0


def _feed(source, **kw):
    return FrameFeed(source, source.intrinsics, load_config("cpu"), **kw)


def _all(feed, warnings=None):
    if warnings is not None:
        feed.warn = warnings.append
    frames = []
    while (frame := feed.next(started=bool(frames))) is not None:
        frames.append(frame)
    return frames


def test_every_frame_after_the_first_is_read_ahead_in_the_prefetch_thread_in_order():
    source = Recorded(6)
    frames = _all(_feed(source))
    assert [f.index for f in frames] == list(range(6))
    assert [float(f.color[0, 0, 0]) for f in frames] == [np.float32(i / 100.0) for i in range(6)]
    assert source.readers[0] == [threading.current_thread().name]
    assert all(source.readers[i] == ["frame-prefetch"] for i in range(1, 6))   # each read once, ahead


def test_stride_and_max_frames_read_ahead_only_the_frames_the_run_takes():
    source = Recorded(20)
    frames = _all(_feed(source, max_frames=4, stride=3))
    assert [f.index for f in frames] == [0, 3, 6, 9]
    assert sorted(source.readers) == [0, 3, 6, 9]       # nothing past the last frame is read


def test_a_bad_frame_read_ahead_is_skipped_with_its_warning():
    source = Recorded(5, bad=[2])
    warnings: list[str] = []
    frames = _all(_feed(source), warnings)
    assert [f.index for f in frames] == [0, 1, 3, 4]
    assert len(warnings) == 1 and "no valid depth" in warnings[0]
    assert source.readers[2] == ["frame-prefetch"]


def test_a_capture_whose_first_frames_are_all_bad_is_still_refused_as_a_whole():
    source = Recorded(12, bad=range(12))
    feed = _feed(source)
    try:
        feed.next(started=False)
    except InputError as e:
        assert "first 10 frames are unusable" in str(e)
    else:
        raise AssertionError("no InputError")


class WatchedLock:
    """A lock that tells when the thread named "evaluation" asks for it."""

    def __init__(self):
        self.lock, self.asked = threading.Lock(), threading.Event()

    def __enter__(self):
        if threading.current_thread().name == "evaluation":
            self.asked.set()
        self.lock.acquire()

    def __exit__(self, *exc):
        self.lock.release()


def test_a_frame_read_while_a_read_ahead_is_in_flight_waits_for_it():
    source = Recorded(5, hold=1)
    feed = _feed(source)
    feed._read_lock = lock = WatchedLock()
    assert feed.next(started=False).index == 0      # the read of frame 1 starts ahead, and is held
    assert source.entered.wait(30)
    other: list = []
    reader = threading.Thread(target=lambda: other.append(feed.frame_at(3)), name="evaluation")
    reader.start()                                  # a reader (an evaluation, a preview) of another frame
    assert lock.asked.wait(30)                      # it asks for the source while frame 1 is being read
    source.release.set()
    reader.join()
    assert other[0].index == 3 and source.most_inside == 1     # never two reads of the source at once
    assert [f.index for f in _all(feed)] == [1, 2, 3, 4]
