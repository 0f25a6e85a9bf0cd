"""Lost tracking when the loss level moves (issue 42, real-time playback): a loss per pixel that rose
over the last tracked frames (a map falling behind a moving camera) is judged against that level, not
against a median taken on frames that fitted a first map unusually well; and a relocalised pose is
not believed when a start pose near the camera fitted the same frame far better."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from splat_core.camera import invert_pose
from splat_core.config import LostTrackingConfig, load_config
from splat_core.relocalise import Evidence, LostTracking, lost_reason
from splat_core.slam import SplaTAM
from splat_core.synthetic import HardCapture
from splat_core.tracking import TrackResult

CFG = LostTrackingConfig()


def ordinary(loss: float) -> Evidence:
    return Evidence(loss_per_pixel=loss, coverage=0.6, translation=0.05, rotation_deg=2.0, seconds=0.3)


def test_a_loss_that_rose_over_the_last_frames_is_judged_against_them():
    # seven frames tracked close to frame 0's map (which fits them unusually well), then three against a
    # map that lags the camera: the median is still the first frames' level
    recent = [0.03] * 7 + [0.15, 0.18, 0.20]
    assert lost_reason(ordinary(0.22), recent, CFG) is None
    assert "x the recent median" in lost_reason(ordinary(0.22), recent, LostTrackingConfig(loss_trend=0))
    # far above the level the last frames reached is still lost, and names it
    assert "the last 3 frames' lowest 0.15" in lost_reason(ordinary(0.80), recent, CFG)
    # one high frame does not raise the bar: the last three must all have reached the level
    spike = [0.03] * 9 + [0.5]
    assert "x the recent median" in lost_reason(ordinary(0.22), spike, CFG)
    assert lost_reason(ordinary(0.22), [0.03] * 7 + [0.5, 0.03, 0.5], CFG) is not None
    # a falling loss changes nothing: the median judges
    assert "x the recent median 0.2" in lost_reason(ordinary(1.2), [0.2] * 7 + [0.05, 0.04, 0.03], CFG)


class ScriptedTracker:
    """Stands in for the relocalising tracker: each start pose's result is given (a start pose is
    found by its camera position)."""

    def __init__(self, results: dict):
        self.results, self.starts = results, []

    def track(self, gaussians, color, depth, w2c_start, reuse=False):
        x = round(float(invert_pose(w2c_start)[0, 3]), 3)
        self.starts.append(x)
        return self.results[x]


def pose_at(x: float) -> np.ndarray:
    c2w = np.eye(4)
    c2w[0, 3] = x
    return invert_pose(c2w)


def result(x: float, per_pixel: float, coverage: float) -> TrackResult:
    depth_pixels = 1000
    valid = int(coverage * depth_pixels)
    return TrackResult(pose_at(x), per_pixel * valid, 10, valid, "aligned", depth_pixels)


def watch_with(results: dict, recent: list[float]) -> LostTracking:
    src = HardCapture("none", n_frames=4, at=1, width=80, height=60)
    slam = SplaTAM(load_config("cpu", {"resolution": [80, 60]}), src.intrinsics)
    watch = LostTracking(CFG, slam.tracker)
    watch.tracker = ScriptedTracker(results)
    watch.recent.extend(recent)
    watch.good = (9, 90, 3.0)                   # the last tracked frame: capture frame 90 at 3 s
    return watch


def test_a_relocalised_pose_that_fits_far_worse_than_a_start_near_the_camera_is_not_believed():
    # The camera pans onto what the map does not hold yet: tracked from where it was, the frame fits well
    # where the map covers it, but the map covers too little (lost). A keyframe far off (0.8 m) gives a
    # pose the map covers, at a loss per pixel that the history's level (5 x 0.19) lets through.
    frame = SimpleNamespace(index=100, timestamp=100 / 30, color=None, depth=None)   # 10 capture frames on
    keyframes = [SimpleNamespace(w2c=pose_at(0.8))]
    near, far = result(0.01, 0.12, 0.20), result(0.80, 0.90, 0.92)
    recent = [0.19] * 10
    watch = watch_with({0.0: near, 0.8: far}, recent)
    best, reason = watch.relocalise(frame, None, pose_at(0.0), keyframes, near, "the map covers 20%")
    assert watch.tracker.starts == [0.0, 0.8]
    assert reason is not None and "from another start" in reason     # lost: its pose is held
    # the jump the relocalisation is for: the keyframe's pose fits, the one near the held pose does not
    stale, jumped = result(0.01, 0.90, 0.90), result(0.80, 0.15, 0.90)
    watch = watch_with({0.0: stale, 0.8: jumped}, recent)
    best, reason = watch.relocalise(frame, None, pose_at(0.0), keyframes, stale, "loss per pixel")
    assert reason is None and best is jumped
