"""SplaTAM: dense RGB-D SLAM with 3D Gaussians. `process(frame)` is one step of the paper:

    w2c0   = predict(previous poses)            constant velocity (scaled by the capture-frame gaps)
    w2c    = tracker.track(frame, map, w2c0)    align -> accept -> polish (tracking.py)
             lost? relocalise                   against the keyframes; still lost: hold the pose, map nothing (relocalise.py)
    new    = densify(frame, map, w2c)           silhouette < 0.5 or new geometry in front
    window = select_window(frame, w2c)          current + latest keyframe + overlapping ones
    prune(map)                                  transparent / huge Gaussians
    optimise_map(map, window)                   L1 + SSIM (pruning again every 20 iterations)
    keyframes.add(frame, w2c)                   every n-th capture frame (at the run's stride)

With frames dropped (real-time playback, a live stream) the motion model's time and the keyframe
interval count capture frames (`frame.index`, at the run's `stride`); with none dropped, the same.

`process` runs the two halves in order (the sequential engine: deterministic, resumable bit for
bit). The live engine (run/live.py) calls `track` and `map_frame` from two threads instead; both
read the map through `MapVersion`s that `publish` makes, never the tensors the mapper is stepping.

SplaTAM is the only writer of its state (map, poses, keyframes, loops); collaborators return
results it applies: lost tracking a Verdict (relocalise.py), loop closure a LoopFound with its
Correction (loop/; the engine chooses the locking: `close_loops(t, guard)`), densification new
Gaussians (densify.py). `state_arrays` / `load_state_arrays` save and load all of it, and
`finish()` ends a run (the end-of-run hole fill and colour fit): slam_checkpoint.py.
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import time

import numpy as np
import torch

from .camera import Intrinsics, invert_pose, predict_constant_velocity
from .color_fit import FitSamples
from .config import Config
from .densify import frame_gaussians
from .frame import Frame
from .gaussians import GaussianMap, Gaussians
from .keyframes import Keyframe, KeyframeStore, is_keyframe_time
from .loop import LoopClosure, anchors
from .loop.records import Correction, LoopRecord
from .mapping import View, optimise_map, prune_mask
from .relocalise import LostTracking
from .render import Renderer
from .slam_checkpoint import SlamState
from .slam_state import FrameResult, MapStats, MapVersion, SlamView, snapshot_version
from .tracking import Tracker, TrackResult, load_optimizer_code

__all__ = ["SplaTAM", "FrameResult", "MapStats", "MapVersion", "snapshot_version"]

NOT_KEYFRAME, KEYFRAME, DEFERRED = 0, 1, 2      # SplaTAM.keyframe_marks


class SplaTAM(SlamState):
    def __init__(self, config: Config, intrinsics: Intrinsics, device="cpu", dtype=torch.float32,
                 total_frames: int | None = None, stride: int = 1):
        self.config = config
        self.intrinsics = intrinsics
        self.device, self.dtype = torch.device(device), dtype
        self.renderer = Renderer(near=config.near_plane)
        self.densify_intrinsics = intrinsics.fraction(config.densify.resolution_scale)
        self.tracker = Tracker(config.tracking, intrinsics, self.renderer, seed=config.seed, device=self.device, dtype=dtype)
        load_optimizer_code()
        self.lost_tracking = LostTracking(config.lost_tracking, self.tracker)
        self.map = GaussianMap.empty(config.isotropic, device=self.device, dtype=dtype)
        self.keyframes = KeyframeStore(config.keyframes, intrinsics)
        self.loop_closure = LoopClosure(config.loop_closure, config.seed) if config.loop_closure.enabled else None
        self.w2cs: list[np.ndarray] = []
        self.sources: list[int] = []             # each processed frame's capture frame index (frame.index)
        # each tracked frame's keyframe decision, made when it was tracked (KEYFRAME, NOT_KEYFRAME, or
        # DEFERRED: due, put off by the live engine while its mapper is behind; the next frame takes it)
        self.keyframe_marks: list[int] = []
        self.stride = stride                      # capture frames between processed ones when none is dropped
        self.loops: list[LoopRecord] = []        # every loop closed, oldest first
        self.scene_radius: float | None = None
        self.rng = np.random.default_rng(config.seed)
        self.total_frames = total_frames          # lets a frame near the end become a keyframe (keyframes.from_end)
        self._version: MapVersion | None = None
        self._version_lock = threading.Lock()
        self._versions_made = 0
        # mapping.final_refine / final_color_fit / final_hole_fill: frames kept for the end-of-run passes
        # (final_refine.py, color_fit.py, final_holes.py; finish()), with their depth for the hole fill
        mapping = config.mapping
        holes = mapping.final_hole_fill > 0
        self.fit_samples = (FitSamples(intrinsics, config.eval_every, keep_depth=holes)
                            if mapping.final_color_fit or holes or mapping.final_refine > 0 else None)

    def _tensor(self, a: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(np.ascontiguousarray(a), dtype=self.dtype, device=self.device)

    # ------------------------------------------------------------------ one SLAM step
    def process(self, frame: Frame, w2c_given: np.ndarray | None = None) -> FrameResult:
        """Track, densify, map and maybe keep `frame` (at the working resolution).

        `w2c_given` skips tracking and uses that pose (mapping with known poses)."""
        t0 = time.perf_counter()
        t, w2c, tracked = self.track(frame, self.map.tensors(detach=True), w2c_given)
        t1 = time.perf_counter()
        stats = self.map_frame(frame, w2c, t)
        loops = self.close_loops(t) if self.is_keyframe(t) else []
        w2c = self.w2cs[t]            # corrected if a loop closed
        return self.result(frame, t, w2c, tracked, stats, len(self.map), t1 - t0, time.perf_counter() - t1,
                           loops=loops)

    @property
    def frames_tracked(self) -> int:
        """Frames whose pose is known (tracked, given or held while lost); the next frame's index."""
        return len(self.w2cs)

    def is_keyframe(self, t: int) -> bool:
        """Frame t is a keyframe: decided when it was tracked (keyframe_due, and not deferred)."""
        return 0 <= t < len(self.keyframe_marks) and self.keyframe_marks[t] == KEYFRAME

    def keyframe_due(self, t: int) -> bool:
        """Frame t (tracked, not lost) falls due as a keyframe: frame 0, the first frame at or past every
        n-th capture frame (at the run's stride) and the one keyframes.from_end from the end (the second-to-last
        by default); or one deferred before is owed."""
        owed = t > 0 and self.keyframe_marks[t - 1] == DEFERRED
        return self.lost_tracking.reason(t) is None and (owed or is_keyframe_time(
            t, self.total_frames, self.config.keyframes.every, self.capture_step(t - 1), self.capture_step(t),
            self.config.keyframes.from_end))

    def _mark_keyframe(self, t: int, defer: bool) -> None:
        """Frame t's decision: a due keyframe kept, or owed on when `defer` (the live mapper is behind)
        or t was lost."""
        owed = t > 0 and self.keyframe_marks[t - 1] == DEFERRED
        due = self.keyframe_due(t)
        self.keyframe_marks.append((DEFERRED if defer else KEYFRAME) if due else DEFERRED if owed else NOT_KEYFRAME)

    def capture_step(self, t: int) -> int:
        """Processed frame t's place in the capture in steps of the stride, from the first frame (t
        itself while no frame was dropped or skipped; t when frame t is not tracked yet, and with
        keyframes.clock processed)."""
        if t < 0 or t >= len(self.sources) or self.config.keyframes.clock == "processed":
            return t
        return (self.sources[t] - self.sources[0]) // self.stride

    def gap_ratio(self, source_index: int) -> float:
        """The capture frames from the newest tracked frame to `source_index` over those between the
        two before it: the constant-velocity prediction's time scale (capped by
        tracking.max_gap_ratio; 1 with every frame processed)."""
        before, last = self.sources[-2], self.sources[-1]
        if source_index - last == last - before or last <= before or source_index <= last:
            return 1.0
        return min((source_index - last) / (last - before), self.config.tracking.max_gap_ratio)

    def result(self, frame: Frame, t: int, w2c: np.ndarray, tracked: TrackResult | None, stats: MapStats,
               num_gaussians: int, tracking_seconds: float, mapping_seconds: float,
               map_version: int = 0, loops=()) -> FrameResult:
        """What the engines report for frame t (one place for both)."""
        return FrameResult(index=t, timestamp=frame.timestamp, w2c=w2c, is_keyframe=self.is_keyframe(t),
                           lost=self.lost_tracking.reason(t), loops=list(loops), num_gaussians=num_gaussians,
                           num_added=stats.added, num_pruned=stats.pruned,
                           tracking_seconds=tracking_seconds, mapping_seconds=mapping_seconds,
                           tracking_loss=tracked.loss if tracked else None,
                           tracking_iterations=tracked.iterations if tracked else 0,
                           tracking_coverage=tracked.coverage if tracked else None,
                           tracking_start=tracked.start if tracked else None, source_index=frame.index,
                           map_version=map_version)

    def track(self, frame: Frame, gaussians: Gaussians, w2c_given: np.ndarray | None = None,
              defer_keyframe: bool = False) -> tuple[int, np.ndarray, TrackResult | None]:
        """The pose of the next frame against `gaussians`; appends it to the trajectory (a lost
        frame: the last tracked pose, see relocalise.py) and decides whether it is a keyframe
        (`defer_keyframe`: a due keyframe is owed to the next frame instead)."""
        t = len(self.w2cs)
        tracked, watch = None, self.lost_tracking
        if t == 0:
            w2c = np.eye(4)
            self.scene_radius = float(frame.depth.max()) / self.config.scene_radius_depth_ratio
            watch.tracked(t, frame)
        elif w2c_given is not None:
            w2c = np.asarray(w2c_given, dtype=np.float64)
            watch.tracked(t, frame)
        else:
            if not watch.active:    # constant velocity from two tracked poses only, never from a lost one
                known = watch.velocity_known(t)
                w2c_before = self.w2cs[-2] if known else None
                w2c_predicted = predict_constant_velocity(self.w2cs[-1], w2c_before,
                                                          self.gap_ratio(int(frame.index)) if known else 1.0)
                tracked = self.tracker.track(gaussians, frame.color, frame.depth, w2c_predicted, reuse=True)
            verdict = watch.check(t, frame, tracked, gaussians, self.w2cs[watch.good[0]], list(self.keyframes))
            for k, w2c_k in verdict.filled.items():
                self.w2cs[k] = w2c_k
            tracked, w2c = verdict.result, verdict.w2c
        self.w2cs.append(w2c)
        self.sources.append(int(frame.index))
        self._mark_keyframe(t, defer_keyframe)
        if self.fit_samples is not None:
            self.fit_samples.offer(t, frame.color, frame.depth)
        return t, w2c, tracked

    def retract(self, t: int) -> None:
        """Forget the newest frame t's pose and lost mark (the live engine tracks it again, against a
        newer map)."""
        if t != len(self.w2cs) - 1:
            raise ValueError(f"retract: frame {t} is not the newest tracked frame ({len(self.w2cs) - 1})")
        self.w2cs.pop()
        self.sources.pop()
        self.keyframe_marks.pop()
        self.lost_tracking.forget(t)
        if self.fit_samples is not None:
            self.fit_samples.drop(t)

    def map_frame(self, frame: Frame, w2c: np.ndarray, t: int, optimise: bool = True,
                  densified=None, stop=None) -> MapStats:
        """Densify from frame t at pose w2c, optimise the map over its window, maybe keep it as a keyframe
        (`densified`: called between densifying and optimising; `stop`: optimise_map's)."""
        if self.lost_tracking.reason(t) is not None:
            return MapStats()       # a lost frame's pose is not known: nothing of it goes into the map
        start = time.perf_counter()
        stats = MapStats(added=self.densify(frame.color, frame.depth, w2c, t))
        if densified is not None:
            densified()
        if optimise and t % self.config.mapping.map_every == 0:
            window = self.select_window(frame.color, frame.depth, w2c)
            stats.pruned = self.prune()
            stats.pruned += self.optimise(window, first=(t == 0), stop=stop)
        if self.is_keyframe(t):
            self.keyframes.add(t, w2c, frame.color, frame.depth)
        stats.seconds = time.perf_counter() - start
        return stats

    def close_loops(self, t: int, guard=contextlib.nullcontext) -> list[LoopRecord]:
        """Loop closure after keyframe t was mapped (splat_core/loop/): the loops accepted now. A
        correction is applied inside `guard()` (the live engine's holds its pose lock and publishes
        the moved map before releasing it), the seam re-mapped after."""
        if self.loop_closure is None:
            return []
        start = time.perf_counter()
        found = self.loop_closure.after_keyframe(self.view(), t)
        if found is None:
            return []
        held = 0.0
        if found.correction is not None:
            with guard():
                begin = time.perf_counter()
                self.apply_correction(found.correction)
            held = time.perf_counter() - begin      # what the live tracker may wait
            self.remap(found.correction)
        record = dataclasses.replace(found.record, seconds=time.perf_counter() - start, apply_seconds=held)
        self.loops.append(record)
        return [record]

    def view(self) -> SlamView:
        """What loop closure reads: the keyframes and the map as they are now (read only)."""
        return SlamView(self.config, self.intrinsics, self.renderer.near, tuple(self.keyframes),
                        self.map.tensors(detach=True), self.map.birth_frame)

    def apply_correction(self, correction: Correction) -> None:
        """Move keyframes, frame poses and Gaussians by the keyframes' corrections (loop/anchors.py)."""
        C = anchors.corrections(correction.old_c2ws, correction.new_c2ws)
        for kf, c2w in zip(self.keyframes, correction.new_c2ws):
            kf.w2c = invert_pose(c2w)
        anchors.move_poses(self.w2cs, correction.keyframe_frames, C)
        anchors.move_gaussians(self.map, correction.keyframe_frames, C)

    def remap(self, correction: Correction) -> None:
        """A short mapping run over the loop's keyframes and their neighbours (the seams)."""
        if correction.remap_keyframes and correction.remap_iterations:
            kfs = list(self.keyframes)
            self.optimise([self.keyframe_view(kfs[p]) for p in correction.remap_keyframes],
                          iterations=correction.remap_iterations)

    def loop_figures(self) -> dict | None:
        """metrics.json's loop figures (None: loop closure is off)."""
        closer = self.loop_closure
        if closer is None:
            return None
        return dict(loops_closed=len(self.loops), loops_rejected=closer.rejected,
                    loops_rejected_by=dict(closer.rejected_by), loops=[r.to_dict() for r in self.loops])

    # ------------------------------------------------------------------ steps
    def densify(self, color, depth, w2c, t) -> int:
        """Add Gaussians where frame t sees what the map lacks (densify.py, `frame_gaussians`)."""
        new = frame_gaussians(self.map, self.renderer, self.densify_intrinsics, color, depth, w2c, t, self.config,
                              device=self.device, dtype=self.dtype)
        self.map.append(new)
        return len(new)

    def select_window(self, color, depth, w2c) -> list[View]:
        """The current view plus the latest keyframe and the keyframes that overlap it most."""
        mc = self.config.mapping
        views = [View(self._tensor(color), self._tensor(depth), w2c)]
        for kf in self.keyframes.select(depth, w2c, mc.window_size - 1, self.rng):
            views.append(self.keyframe_view(kf))
        return views

    def render_view(self, w2c: np.ndarray):
        """The map rendered at w2c, no gradients (evaluation, previews)."""
        with torch.no_grad():
            return self.renderer.render_visible(self.map.tensors(detach=True), self.intrinsics, w2c)

    def keyframe_view(self, kf: Keyframe) -> View:
        return View(self._tensor(kf.color), self._tensor(kf.depth), kf.w2c)

    def prune(self) -> int:
        """Remove nearly transparent and oversized Gaussians (mapping's iteration-0 pruning)."""
        return self.map.prune(prune_mask(self.map, self.config.mapping, self.scene_radius))

    def optimise(self, window: list[View], first: bool = False, iterations: int | None = None, stop=None) -> int:
        mc = self.config.mapping
        if iterations is None:
            iterations = mc.first_frame_iterations if (first and mc.first_frame_iterations is not None) \
                else mc.iterations
        if first:       # frame 0 anchors every later pose: its long first mapping draws every tile (but `live`)
            mc = dataclasses.replace(mc, tile_fraction=mc.first_frame_tile_fraction)
        stats = optimise_map(self.map, window, self.intrinsics, mc, iterations, self.scene_radius, self.rng,
                             renderer=self.renderer, stop=stop)
        return stats["pruned"]

    # ------------------------------------------------------------------ map versions
    def publish(self, frame_index: int) -> MapVersion:
        """Make the current map the latest version (copy-on-publish: later steps never touch it)."""
        with self._version_lock:
            self._versions_made += 1
            self._version = snapshot_version(self.map, self._versions_made, frame_index, tuple(self.loops))
            return self._version

    def latest_version(self) -> MapVersion | None:
        """The newest version, ready for the calling thread's CUDA stream (MapVersion.wait_ready)."""
        with self._version_lock:
            version = self._version
        return version.wait_ready() if version is not None else None
