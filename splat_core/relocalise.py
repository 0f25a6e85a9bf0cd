"""Lost tracking: detected from the tracker's own numbers, held, and relocalised against the keyframes.

    watch = LostTracking(config.lost_tracking, tracker)
    verdict = watch.check(t, frame, tracked, gaussians, w2c_good, keyframes)   # SplaTAM applies it

A tracked pose is not believed (the frame is *lost*, `lost_reason`) when
    the map's silhouette covers too little of the frame's valid depth (min_coverage): the camera
        looks where the map is not, and a loss over the few covered pixels proves nothing;
    its loss per pixel is far above the recent tracked frames' median (loss_factor x median) and
        above loss_factor x the lowest of the last `loss_trend` frames' (a loss that rose over each
        of them is the level now: a live map that lags a moving camera fits every frame worse, and a
        median still holding the first frames, fitted by frame 0's own map, called them lost);
    the camera moved or turned faster since the last tracked frame than a hand-held camera does
        (max_speed, max_turn_rate_deg over the time between the two frames' timestamps, so
        --stride, skipped and dropped frames widen the limits; at least the capture-frame gap at
        30 fps, for captures whose timestamps do not advance).
A lost frame is relocalised at once: the tracker runs again from other start poses (the last
tracked pose, the newest keyframes, keyframes spread over the run) and the best start the same
rule accepts (`beats` among those) is the frame's pose, unless its loss per pixel is above
loss_factor x the lowest any start (or the first tracking) reached on this frame. None accepted:
the frame stays lost, its pose is the last tracked pose (held, never extrapolated), SplaTAM
neither densifies nor maps from it nor keeps it as a keyframe, and the next frame goes straight
to relocalisation (no constant-velocity prediction runs from a lost pose, nor from the jump a
relocalisation found). Once a frame is accepted, tracking resumes normally, and the lost frames'
held poses in the trajectory are replaced by poses interpolated between the tracked frames on
either side (by frame number; a better guess of where the camera was than the held pose, used by
nothing but the trajectory and its ATE: those frames stay out of the map and of the render metrics).
"""

from __future__ import annotations

import dataclasses
import json
from collections import deque
from dataclasses import dataclass

import numpy as np

from .camera import invert_pose, pose_matrix, quat_to_rotmat_np, rotmat_to_quat
from .config import LostTrackingConfig
from .frame import Frame
from .gaussians import Gaussians
from .tracking import Candidate, Tracker, TrackResult, beats

NOMINAL_FPS = 30.0       # frames per second assumed where timestamps do not advance


@dataclass
class Evidence:
    """The numbers one tracked pose is judged by."""

    loss_per_pixel: float        # the tracking loss over its pixels (inf: no pixel)
    coverage: float | None       # fraction of the loss's valid-depth pixels the map covers (None: unknown)
    translation: float           # metres moved since the last tracked frame
    rotation_deg: float          # degrees turned since then
    seconds: float               # time since then (> 0)


def lost_reason(e: Evidence, recent: list[float], config: LostTrackingConfig) -> str | None:
    """Why the pose is not believed, or None. `recent`: loss per pixel of the last tracked frames."""
    if e.coverage is not None and e.coverage < config.min_coverage:
        return f"the map covers {100 * e.coverage:.0f}% of the frame's depth (< {100 * config.min_coverage:.0f}%)"
    if len(recent) >= config.min_history:
        median, k = float(np.median(recent)), config.loss_trend
        rising = min(recent[-k:]) if 0 < k <= len(recent) else 0.0    # the loss level the last k frames all reached
        if not e.loss_per_pixel <= config.loss_factor * max(median, rising):
            against = f"the recent median {median:.3g}" if median >= rising else \
                f"the last {k} frames' lowest {rising:.3g}"
            return f"loss per pixel {e.loss_per_pixel:.3g} > {config.loss_factor:g} x {against}"
    if e.translation > config.max_speed * e.seconds:
        return f"moved {100 * e.translation:.0f} cm in {e.seconds:.2f} s"
    if e.rotation_deg > config.max_turn_rate_deg * e.seconds:
        return f"turned {e.rotation_deg:.0f} degrees in {e.seconds:.2f} s"
    return None


def per_pixel(result: TrackResult) -> float:
    """The tracking loss per loss pixel (inf: none, or nothing evaluated)."""
    return result.loss / result.valid_pixels if result.valid_pixels and result.loss is not None else np.inf


def relative_motion(w2c_a: np.ndarray, w2c_b: np.ndarray) -> tuple[float, float]:
    """(metres, degrees) between two camera poses."""
    c2w_a, c2w_b = invert_pose(w2c_a), invert_pose(w2c_b)
    cos = (np.trace(c2w_a[:3, :3].T @ c2w_b[:3, :3]) - 1.0) / 2.0
    return float(np.linalg.norm(c2w_a[:3, 3] - c2w_b[:3, 3])), float(np.degrees(np.arccos(np.clip(cos, -1, 1))))


def interpolate_pose(w2c_a: np.ndarray, w2c_b: np.ndarray, s: float) -> np.ndarray:
    """The camera pose a fraction s of the way from a to b (position linear, rotation along the geodesic)."""
    c2w_a, c2w_b = invert_pose(w2c_a), invert_pose(w2c_b)
    q = rotmat_to_quat(c2w_a[:3, :3].T @ c2w_b[:3, :3])            # w >= 0: the shorter way round
    angle = 2.0 * np.arccos(np.clip(q[0], -1.0, 1.0))
    axis = q[1:] / np.linalg.norm(q[1:]) if angle > 1e-12 else np.zeros(3)
    step = quat_to_rotmat_np(np.r_[np.cos(s * angle / 2), np.sin(s * angle / 2) * axis])
    return invert_pose(pose_matrix(c2w_a[:3, :3] @ step, (1 - s) * c2w_a[:3, 3] + s * c2w_b[:3, 3]))


@dataclass
class Verdict:
    """What LostTracking.check returns for one frame."""

    result: TrackResult | None          # the tracker's result to report
    w2c: np.ndarray                     # the frame's pose (the last tracked one while lost)
    filled: dict = dataclasses.field(default_factory=dict)   # lost frames' poses, interpolated now it is found


class LostTracking:
    """Which frames are lost, and the relocalisation of a lost frame (see the module docstring)."""

    def __init__(self, config: LostTrackingConfig, tracker: Tracker):
        self.config = config
        tc = tracker.config
        search = dataclasses.replace(tc, align=dataclasses.replace(
            tc.align, iterations=max(tc.align.iterations, config.align_iterations),
            passes=max(tc.align.passes, config.align_passes)))
        # The tracker again, with a wider reach (more alignment passes); it shares the tracker's pixel
        # choice (one random stream, checkpointed with the tracker).
        self.tracker = Tracker(search, tracker.intrinsics, tracker.renderer, device=tracker.device, dtype=tracker.dtype)
        self.tracker.rng = tracker.rng
        self.recent: deque = deque(maxlen=config.loss_history)   # loss per pixel of tracked frames
        self.lost: dict[int, str] = {}       # processed-frame number -> why it is lost
        self.good = (0, 0, 0.0)              # (processed-frame number, capture frame, timestamp) of the last tracked frame
        self.relocalised = -1                # the newest frame whose pose came from relocalisation

    @property
    def active(self) -> bool:
        """The newest frame is lost: the next one goes straight to relocalisation."""
        return max(self.lost, default=-1) > self.good[0]

    def reason(self, t: int) -> str | None:
        return self.lost.get(t)

    def velocity_known(self, t: int) -> bool:
        """Frames t-2 and t-1 were tracked one after the other: their motion is the camera's (not a
        jump that relocalisation found, nor a held pose), so constant velocity may predict frame t."""
        return t > 1 and self.good[0] == t - 1 and self.relocalised != t - 1 and (t - 2) not in self.lost

    def tracked(self, t: int, frame: Frame, result: TrackResult | None = None) -> None:
        """Frame t's pose is believed (tracked, relocalised, given, or the first frame)."""
        self.good = (t, int(frame.index), float(frame.timestamp))
        if result is not None and result.valid_pixels > 0 and np.isfinite(result.loss):
            self.recent.append(result.loss / result.valid_pixels)

    # -------------------------------------------------------------- one frame
    def check(self, t: int, frame: Frame, tracked: TrackResult | None, gaussians: Gaussians,
              w2c_good: np.ndarray, keyframes: list) -> "Verdict":
        """Frame t's verdict. `tracked`: the tracker's result from the constant-velocity prediction,
        None while lost (relocalisation only); `w2c_good`: the pose of the last tracked frame
        (`self.good[0]`). Changes only this watch's own state; SplaTAM applies the verdict."""
        if not self.config.enabled:
            self.tracked(t, frame, tracked)
            return Verdict(tracked, tracked.w2c)
        reason = "tracking was lost" if tracked is None else self.judge(tracked, w2c_good, frame)
        relocalised = reason is not None
        if relocalised:
            tracked, reason = self.relocalise(frame, gaussians, w2c_good, keyframes, tracked, reason)
        if reason is None:
            self.relocalised = t if relocalised else self.relocalised
            good = self.good[0]
            filled = {k: interpolate_pose(w2c_good, tracked.w2c, (k - good) / (t - good))
                      for k in range(good + 1, t)}       # the lost frames since the last tracked one
            self.tracked(t, frame, tracked)
            return Verdict(tracked, tracked.w2c, filled)
        self.lost[t] = reason
        return Verdict(tracked, w2c_good.copy())

    def forget(self, t: int) -> None:
        """Frame t is tracked again (the live engine's retry): drop its lost mark."""
        self.lost.pop(t, None)

    def judge(self, result: TrackResult, w2c_good: np.ndarray, frame: Frame) -> str | None:
        loss = per_pixel(result)
        if result.loss is None:          # nothing evaluated (no polish stage): motion only
            loss = float(np.median(self.recent)) if self.recent else 0.0
        metres, degrees = relative_motion(w2c_good, result.w2c)
        seconds = max(frame.timestamp - self.good[2], max(1, frame.index - self.good[1]) / NOMINAL_FPS)
        return lost_reason(Evidence(loss, result.coverage, metres, degrees, seconds), list(self.recent), self.config)

    def relocalise(self, frame: Frame, gaussians: Gaussians, w2c_good: np.ndarray, keyframes: list,
                   failed: TrackResult | None, why: str) -> tuple[TrackResult | None, str | None]:
        """Track the frame from each start pose; the best one `judge` accepts, or the best failure. A
        pose whose loss per pixel is more than loss_factor x the lowest any start (or the tracker)
        reached on this frame is not believed either: the same frame against the same map fits that
        much better elsewhere (a start near the camera that the map covers too little of, a pose
        far off that it covers)."""
        results = [self.tracker.track(gaussians, frame.color, frame.depth, w2c_start)
                   for w2c_start in self.starts(w2c_good, keyframes)]
        lowest = min((per_pixel(r) for r in results + [failed] if r is not None), default=np.inf)
        best, best_reason = failed, why
        best_ok: Candidate | None = None
        for result in results:
            reason = self.judge(result, w2c_good, frame)
            if reason is None and not per_pixel(result) <= self.config.loss_factor * lowest:
                reason = (f"loss per pixel {per_pixel(result):.3g} > {self.config.loss_factor:g} x "
                          f"{lowest:.3g} from another start")
            here = Candidate("relocalised", result.w2c, result.loss if result.loss is not None else np.inf,
                             result.valid_pixels)
            if reason is None and (best_ok is None or beats(here, best_ok)):
                best, best_reason, best_ok = result, None, here
            elif best_ok is None and (best is None or result.valid_pixels > best.valid_pixels):
                best, best_reason = result, reason
        return best, best_reason

    def starts(self, w2c_good: np.ndarray, keyframes: list) -> list[np.ndarray]:
        """The last tracked pose, the newest keyframes, keyframes spread over the run (no repeats)."""
        c = self.config
        picks = list(range(len(keyframes)))[::-1][: c.recent_keyframes]
        if c.spread_keyframes and keyframes:
            picks += [int(i) for i in np.linspace(0, len(keyframes) - 1, c.spread_keyframes).round()]
        starts = [np.asarray(w2c_good, np.float64)]
        for i in dict.fromkeys(picks):
            w2c = np.asarray(keyframes[i].w2c, np.float64)
            if not any(np.allclose(w2c, s) for s in starts):
                starts.append(w2c)
        return starts

    # -------------------------------------------------------------- checkpoints
    def state(self) -> str:
        return json.dumps(dict(recent=list(self.recent), lost=self.lost, good=self.good, relocalised=self.relocalised))

    def load_state(self, state: str) -> None:
        s = json.loads(state)
        self.recent.clear()
        self.recent.extend(s["recent"])
        self.lost = {int(k): v for k, v in s["lost"].items()}
        self.good, self.relocalised = tuple(s["good"]), int(s["relocalised"])
