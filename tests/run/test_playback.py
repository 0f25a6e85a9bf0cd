"""`--realtime` playback (splat_core/io/playback.py): a capture handed to SLAM as a live stream
would be, newest frame first, with the dropped frames counted. A fake clock that the test (and the
playback's `sleep`) advances: nothing here waits on wall time."""

from __future__ import annotations

import numpy as np
import pytest

from splat_core.errors import InputError
from splat_core.frame import Frame
from splat_core.intrinsics import Intrinsics
from splat_core.io.playback import RealtimePlayback, arrival_times
from splat_core.io.source import FrameSource


class FakeClock:
    def __init__(self, now: float = 1000.0):
        self.now, self.slept = now, []

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.now += seconds

    def advance(self, seconds: float) -> None:
        self.now += seconds


class Stamped(FrameSource):
    """n tiny frames with the given timestamps."""
    format_name = "test"

    def __init__(self, stamps):
        self._stamps = np.asarray(stamps, np.float64)

    def __len__(self):
        return len(self._stamps)

    def __getitem__(self, i):
        return Frame(i, float(self._stamps[i]), np.full((4, 4, 3), 0.5, np.float32), np.ones((4, 4), np.float32),
                     self.intrinsics, np.eye(4))

    @property
    def intrinsics(self):
        return Intrinsics(4.0, 4.0, 2.0, 2.0, 4, 4)

    @property
    def timestamps(self):
        return self._stamps


def _playback(stamps, fps=None, **kw):
    clock = FakeClock()
    return RealtimePlayback(Stamped(stamps), fps, clock=clock, sleep=clock.sleep, **kw), clock


def test_first_frame_at_once_and_the_clock_starts_at_the_second_request():
    play, clock = _playback(np.arange(10) / 10.0)
    assert play.next_index() == 0 and clock.slept == []
    clock.advance(5.0)                    # frame 0 is mapped for 5 s: the clock is not running yet
    assert play.next_index() == 1          # waits 0.1 s for frame 1; nothing dropped
    assert clock.slept == [pytest.approx(0.1)]
    assert (play.received, play.dropped, play.delivered) == (2, 0, 2)


def test_newest_frame_handed_over_and_the_dropped_ones_counted():
    play, clock = _playback(np.arange(10) / 10.0)
    play.next_index(), play.next_index()       # frames 0 and 1 (the clock runs from frame 0's time at the 2nd)
    clock.advance(0.35)                         # 0.45 s after frame 0: frames 2, 3, 4 have arrived
    frame = play.next_frame()
    assert frame.index == 4 and frame.timestamp == pytest.approx(0.4)
    assert (play.received, play.delivered, play.dropped) == (5, 3, 2)
    assert play.stats()["processed_share"] == pytest.approx(3 / 5)
    assert play.next_index() == 5 and play.dropped == 2        # a fast consumer waits, drops nothing


def test_the_end_of_the_capture_ends_the_playback_with_the_last_frame_handed_over():
    play, clock = _playback(np.arange(6) / 10.0)
    play.next_index(), play.next_index()
    clock.advance(100.0)
    assert play.next_index() == 5              # everything arrived: the last frame, 2..4 dropped
    assert play.next_frame() is None and play.next_index() is None
    assert (play.received, play.delivered, play.dropped) == (6, 3, 3)
    assert len(play) == 6 and len(play.timestamps) == 6


def test_arrival_from_timestamps_fps_or_30_when_they_are_unusable():
    play, clock = _playback([5.0, 5.1, 5.6, 5.7])
    assert [play.next_index() for _ in range(5)] == [0, 1, 2, 3, None]
    assert clock.slept == pytest.approx([0.1, 0.5, 0.1])
    assert arrival_times([5.0, 5.0, 5.0], 3)[0] == pytest.approx([0, 1 / 30, 2 / 30])
    assert arrival_times([0.0, np.nan, 0.2], 3)[1] == 30.0
    assert arrival_times([0.0, 0.2, 0.1], 3)[1] == 30.0
    assert arrival_times([0.0, 0.2, 0.1], 3, fps=4)[0] == pytest.approx([0, 0.25, 0.5])
    with pytest.raises(InputError):
        arrival_times([0.0, 1.0], 2, fps=0)


def test_max_frames_timeout_and_stop():
    play, clock = _playback(np.arange(10) / 10.0, max_frames=3)
    play.next_index(), play.next_index()
    assert play.next_index(timeout=0.01) is None and clock.slept[-1] == pytest.approx(0.01)
    assert play.next_index() == 2 and play.next_index() is None    # the first 3 frames only
    play, _ = _playback(np.arange(10) / 10.0)
    play.next_index()
    play.stop()
    assert play.next_index() is None


def _playback_pipeline(n_frames: int, **overrides):
    """(fake clock, Pipeline) on a 10 frames/s real-time playback of n synthetic 80x60 frames, `cpu`
    preset with light mapping; `overrides`: more settings sections."""
    from splat_core.config import load_config
    from splat_core.run import Pipeline
    from splat_core.synthetic import SyntheticSource

    clock = FakeClock()
    play = RealtimePlayback(SyntheticSource(n_frames=n_frames, width=80, height=60, seed=0), fps=10.0,
                            clock=clock, sleep=clock.sleep)
    config = load_config("cpu", overrides={"resolution": [80, 60], "checkpoint_every": 0, "eval_every": 100,
                                           "mapping": {"first_frame_iterations": 5, "iterations": 2},
                                           "loop_closure": {"enabled": False}, **overrides})
    return clock, Pipeline(play, config)


def test_a_pipeline_on_a_playback_processes_the_newest_frames_and_reports_the_drops():
    clock, pipe = _playback_pipeline(10)
    process = pipe.engine.process

    def slow(frame, given=None):          # SLAM takes 0.2 s a frame on the fake clock
        clock.advance(0.2)
        return process(frame, given)
    pipe.engine.process = slow
    while pipe.step() is not None:
        pass
    assert [r["source_index"] for r in pipe.records] == [0, 1, 3, 5, 7, 9]
    metrics = pipe.finish()
    assert (metrics["frames"], metrics["received"], metrics["dropped"]) == (6, 10, 4)
    assert metrics["processed_share"] == pytest.approx(0.6)


def test_a_playback_that_drops_frames_unevenly_scales_the_prediction_and_keyframes_by_capture_frames():
    # SLAM takes 0.1, 0.3, 0.1, 0.5 s a frame in turn on the fake clock at 10 frames/s: the gaps
    # between processed frames are uneven. The constant-velocity prediction of each frame scales
    # the last motion by the ratio of the capture-frame gaps (capped), and keyframes fall on the
    # first frame at or past every 5th capture frame, not on every 5th processed frame.
    from splat_core.camera import predict_constant_velocity
    from splat_core.keyframes import is_keyframe_time

    clock, pipe = _playback_pipeline(30, tracking={"max_gap_ratio": 2.5})
    slam = pipe.engine.slam
    process, track = pipe.engine.process, slam.tracker.track
    durations = iter([0.1, 0.3, 0.1, 0.5] * 30)
    predictions = []

    def slow(frame, given=None):
        clock.advance(next(durations))
        return process(frame, given)

    def tracked(gaussians, color, depth, w2c_predicted, reuse=False):
        if len(slam.w2cs) >= 2 and slam.lost_tracking.velocity_known(len(slam.w2cs)):
            predictions.append((list(slam.sources[-2:]), slam.w2cs[-2].copy(), slam.w2cs[-1].copy(),
                                w2c_predicted.copy()))
        return track(gaussians, color, depth, w2c_predicted, reuse)
    pipe.engine.process, slam.tracker.track = slow, tracked
    while pipe.step() is not None:
        pass
    sources = [r["source_index"] for r in pipe.records]
    gaps = np.diff(sources)
    assert len(set(gaps.tolist())) > 1 and pipe.finish()["dropped"] > 0       # frames were dropped unevenly
    ratios = []
    for (before, last), w2c_before, w2c_last, predicted in predictions:
        now = sources[sources.index(last) + 1]
        ratio = min((now - last) / (last - before), 2.5)
        ratios.append(ratio)
        assert np.allclose(predicted, predict_constant_velocity(w2c_last, w2c_before, ratio), atol=1e-12)
    assert any(r > 1 for r in ratios) and any(r < 1 for r in ratios) and 2.5 in ratios   # the cap was met
    some = next(p for p, r in zip(predictions, ratios) if r != 1)
    assert not np.allclose(some[3], predict_constant_velocity(some[2], some[1]))          # not the unscaled one
    keyframes = [r["source_index"] for r in pipe.records if r["is_keyframe"]]
    assert keyframes == [s for t, s in enumerate(sources) if not pipe.records[t]["lost"] and
                         is_keyframe_time(t, None, 5, sources[t - 1] if t else -1, s)]
    assert keyframes != [s for t, s in enumerate(sources) if is_keyframe_time(t, None, 5)]


def test_realtime_refuses_resume_stride_and_a_stream(tmp_path):
    from app.run_setup import setup_run

    with pytest.raises(InputError, match="--realtime does not go with --resume or --stride"):
        setup_run("synthetic", out=tmp_path / "a", realtime=0.0, stride=2, device="cpu")
    with pytest.raises(InputError, match="nerfcapture:// already arrives in real time"):
        setup_run("nerfcapture://", out=tmp_path / "b", realtime=15.0, device="cpu")
    run = setup_run("synthetic", out=tmp_path / "c", realtime=0.0, max_frames=4, device="cpu")
    assert run.realtime and run.live and run.source.count == 4 and run.max_frames is None
