"""Keyframes (keyframes.py): the schedule, overlap and window selection, compact storage and spilling."""

from __future__ import annotations

import numpy as np
import pytest

from splat_core.camera import (pose_matrix, quat_to_rotmat_np)
from splat_core.config import KeyframeConfig
from splat_core.keyframes import KeyframeStore, is_keyframe_time, overlap_scores

from helpers.engine import small_source


def test_keyframe_schedule():
    assert [t for t in range(12) if is_keyframe_time(t, 12, 5)] == [0, 4, 9, 10]
    # keyframes.from_end 1 (the `live` preset): the last frame instead of the second-to-last; on a
    # length that is a multiple of `every` the last frame is a keyframe already, and nothing is added.
    assert [t for t in range(12) if is_keyframe_time(t, 12, 5, from_end=1)] == [0, 4, 9, 11]
    assert [t for t in range(10) if is_keyframe_time(t, 10, 5, from_end=1)] == [0, 4, 9]
    assert [t for t in range(10) if is_keyframe_time(t, 10, 5)] == [0, 4, 8, 9]


def test_keyframe_schedule_in_capture_frames_when_frames_were_dropped():
    # Every frame processed: the capture rule is the processed-frame rule.
    assert [t for t in range(12) if is_keyframe_time(t, 12, 5, t - 1, t)] == [0, 4, 9, 10]
    # Capture frames 0, 1, 3, 7, 8, 15, 16, 30 processed: the first frame at or past capture frames
    # 4, 9, 14, ... (every 5th) becomes a keyframe, as when every frame is processed.
    steps = [0, 1, 3, 7, 8, 15, 16, 30]
    chosen = [t for t in range(len(steps)) if is_keyframe_time(t, None, 5, steps[t - 1] if t else -1, steps[t])]
    assert [steps[t] for t in chosen] == [0, 7, 15, 30]


def test_overlap_scores_and_window_selection():
    src = small_source(n=1, w=64, h=48)
    f = src[0]
    intr = f.intrinsics
    turned = pose_matrix(quat_to_rotmat_np([np.cos(0.25), 0, np.sin(0.25), 0]), [0, 0, 0])  # 29 deg yaw
    behind = pose_matrix(quat_to_rotmat_np([0, 0, 1, 0]), [0, 0, 0])                       # 180 deg
    store = KeyframeStore(KeyframeConfig(overlap_border=2), intr)      # a 64x48 image: small border
    for i, w2c in enumerate([behind, np.eye(4), turned, behind]):
        store.add(i, w2c, f.color, f.depth)
    scores = overlap_scores(f.depth, np.eye(4), intr, store.items[:-1], np.random.default_rng(0), border=2)
    assert scores[1] > 0.8 and 0 < scores[2] < scores[1] and scores[0] == 0
    window = store.select(f.depth, np.eye(4), k=3, rng=np.random.default_rng(0))
    assert [kf.frame_index for kf in window] == [1, 2, 3]      # top overlaps, then the latest
    window = store.select(f.depth, np.eye(4), k=2, rng=np.random.default_rng(0))
    assert [kf.frame_index for kf in window] == [1, 3]


def test_overlap_within_depth_drops_keyframes_that_never_measured_the_view():
    # A keyframe far back on the same line of sight projects today's points inside its image
    # (SplaTAM's test counts it), but they lie beyond the farthest depth it measured.
    src = small_source(n=1, w=64, h=48)
    f = src[0]
    intr = f.intrinsics
    far = float(f.depth.max())
    back = pose_matrix(np.eye(3), [0, 0, 3 * far])               # w2c: the camera 3 x far behind
    near_back = pose_matrix(np.eye(3), [0, 0, 0.02 * far])
    store = KeyframeStore(KeyframeConfig(overlap_border=2), intr)
    for i, w2c in enumerate([back, near_back]):
        store.add(i, w2c, f.color, f.depth)
    def scores(within):
        return overlap_scores(f.depth, np.eye(4), intr, store.items, np.random.default_rng(0), 1600, 2, within)
    plain, ranged = scores(False), scores(True)
    assert plain[0] > 0.5 and ranged[0] == 0.0
    assert ranged[1] == pytest.approx(plain[1]) and ranged[1] > 0.5


def test_keyframes_are_compact_and_spill_to_their_file_unchanged(tmp_path):
    f = small_source(n=1, w=64, h=48, noise=0.002)[0]
    store = KeyframeStore(KeyframeConfig(memory_mb=0.02), f.intrinsics)     # room for one 64x48 keyframe
    store.attach(tmp_path / "keyframes.bin")
    for i in range(3):
        store.add(i, np.eye(4), f.color, f.depth)
    assert store.resident_bytes() == 64 * 48 * 5                              # uint8 colour + uint16 depth
    assert [kf.resident for kf in store] == [False, False, True]
    assert (tmp_path / "keyframes.bin").stat().st_size == 3 * 64 * 48 * 5
    for kf in store:                                                          # read back from the file
        assert kf.color.dtype == np.float32 and np.abs(kf.color - f.color).max() <= 0.5 / 255 + 1e-7
        assert np.abs(kf.depth - f.depth).max() <= 0.5 * f.depth.max() / 65535 + 1e-6
        assert np.array_equal(kf.depth > 0, f.depth > 0)
    # A resumed store reads the checkpoint's records and drops what was appended after them.
    arrays = store.to_arrays()
    store.add(3, np.eye(4), f.color, f.depth)
    again = KeyframeStore(KeyframeConfig(memory_mb=0.02), f.intrinsics)
    again.load_arrays(arrays, tmp_path / "keyframes.bin")
    assert len(again) == 3 and (tmp_path / "keyframes.bin").stat().st_size == 3 * 64 * 48 * 5
    assert all(np.array_equal(a.depth, b.depth) and np.array_equal(a.color, b.color) for a, b in zip(store, again))


def test_keyframes_spill_without_a_run_folder():
    f = small_source(n=1, w=64, h=48)[0]
    store = KeyframeStore(KeyframeConfig(memory_mb=0), f.intrinsics)
    kf = store.add(0, np.eye(4), f.color, f.depth)
    assert store.resident_bytes() == 0 and not kf.resident
    assert np.abs(kf.color - f.color).max() <= 0.5 / 255 + 1e-7
    store.close()                                                             # back in memory, still readable
    assert kf.resident and np.abs(kf.color - f.color).max() <= 0.5 / 255 + 1e-7
