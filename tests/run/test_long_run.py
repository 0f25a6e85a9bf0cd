"""What a long run holds per frame: counted (allocations that stay), never timed."""

from __future__ import annotations

import tracemalloc

import numpy as np

from splat_core.config import load_config
from splat_core.run import Pipeline
from splat_core.synthetic import SyntheticSource
from splat_core.synthetic import PERIOD, CorridorSource


def test_a_frame_leaves_behind_only_its_keyframe_and_a_few_numbers(tmp_path):
    # numpy and Python allocations that stay from frame 20 to frame 40 (what one iteration holds
    # at any time is there at both counts and cancels): the keyframes' compact images (uint8 +
    # uint16) and per frame a record, poses and the small objects of the step in flight (3.6 KB
    # measured). Keeping a frame's images (80x60 float32 colour + depth: 77 KB a frame) or float32
    # keyframes (10.5 KB a frame more) fails this.
    cfg = load_config("cpu", overrides={"resolution": [80, 60], "tracking": {"use_reference_poses": True},
                                        "mapping": {"iterations": 1, "first_frame_iterations": 5},
                                        "checkpoint_every": 0})
    pipe = Pipeline(SyntheticSource(n_frames=50, width=80, height=60, speed=2.0), cfg, tmp_path / "run")
    for _ in range(10):
        pipe.step()
    tracemalloc.start()
    start = tracemalloc.take_snapshot()

    def held() -> int:
        ahead = pipe.feed._ahead._thread          # the next frame's read, in a thread: let it end, so
        if ahead is not None:                     # both counts hold the read-ahead frame (77 KB)
            ahead.join()
        return sum(s.size_diff for s in tracemalloc.take_snapshot().compare_to(start, "filename"))
    for _ in range(10):
        pipe.step()
    held_20, keyframes_20 = held(), len(pipe.engine.slam.keyframes)
    for _ in range(20):
        pipe.step()
    held_40, keyframes_40 = held(), len(pipe.engine.slam.keyframes)
    tracemalloc.stop()
    assert keyframes_40 - keyframes_20 == 4
    per_frame = (held_40 - held_20 - 4 * 80 * 60 * 5) / 20
    assert per_frame < 6 * 1024, per_frame


def test_the_corridor_keeps_showing_new_geometry():
    src = CorridorSource(n_frames=1000, width=40, height=30)
    first, last = src.c2w[0][:3, 3], src.c2w[-1][:3, 3]
    assert 14 < last[0] - first[0] < 16                     # 1.5 cm a frame along the corridor
    assert all((src[i].depth > 0).mean() > 0.3 for i in (0, 500, 999))
    # the motion repeats after PERIOD frames (the benchmark compares frames 100-200 with 900-1000)
    a, b = src.c2w[150], src.c2w[150 + PERIOD]
    assert np.allclose(a[:3, :3], b[:3, :3]) and np.allclose(b[:3, 3] - a[:3, 3], [PERIOD * 0.015, 0, 0])
