"""The live engine: the caller's thread tracks every frame while a mapper thread maps.

    engine = LiveEngine(slam, config.live)
    result = engine.process(frame)      # tracks against the newest map version, hands the frame over
    engine.drain()                      # wait until everything handed over is mapped (checkpoints, the end)
    engine.close()

Same interface as the sequential engine (engines.py).
The tracker (the thread that calls `process`: the pipeline's, the viewer's worker) tracks each frame
against the newest `MapVersion` the mapper published and hands (frame, pose) to the mapper. The
mapper takes everything handed over since its last step, and in one step:
    densifies from each keyframe among them and from the newest frame (the others add little that
    the newest does not: they sit between the two; with `live.map: keyframes` the newest frame only
    densifies, `live.densify_between`),
    optimises the map over the newest frame's window (current + latest keyframe + overlapping
    keyframes, SplaTAM's window), prunes, and keeps the keyframes,
    publishes a new MapVersion (a copy: nothing renders a tensor the mapper is stepping).

Hand-over policy (docs/engines.md has the measurements): frame 0 is mapped before frame 1 is
tracked; after that the tracker waits while the newest published version is more than
`live.max_lag` frames behind the frame it is about to track. With `live.wait: false` (the `live`
preset) it never waits after frame 0 but for `live.max_keyframe_lag` (keyframes handed over and
unmapped) on a capture read frame by frame; on a live source (stream, real-time playback) a
keyframe falling due meanwhile is deferred instead (`live.pace_keyframes`; SplaTAM.keyframe_marks:
owed by the next frames until one is tracked with the mapper caught up), and a frame the map
covers too little of cuts the mapper's step short (`live.hurry_coverage`). `stats()` reports the
lag in frames and keyframes.

Cores: under Numba's thread-safe "omp" layer both threads run kernels at once (parallel.numba_lock),
each over all cores. GPU: the mapper runs on its own CUDA stream (mapper_stream); a published
version carries an event that readers' streams wait for (MapVersion.wait_ready).

Results are not bitwise reproducible (which frames a mapper step covers depends on timing); the
sequential engine (SplaTAM.process) is the deterministic reference.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque

import numpy as np

from ..config import LiveConfig
from ..device import mapper_stream
from ..frame import Frame
from ..slam import DEFERRED, FrameResult, MapStats, MapVersion, SplaTAM
from .slam_reads import SlamReads


class LiveEngine(SlamReads):
    def __init__(self, slam: SplaTAM, config: LiveConfig, live_source: bool = False):
        self.slam, self.config = slam, config
        # live.pace_keyframes on this input (live.pace_sources): a due keyframe is deferred while the
        # mapper is behind, instead of the tracker waiting (max_keyframe_lag)
        self.paced = config.pace_keyframes is not None and not config.wait and \
            (live_source or config.pace_sources == "all")
        self._cond = threading.Condition()
        self._pending: deque = deque()      # (t, frame, w2c) handed over, not yet mapped
        self._handed = -1                   # newest frame index handed over
        self._mapped = slam.frames_tracked - 1   # newest frame index in a published version (resume: all)
        self._closing = False
        self.error: BaseException | None = None
        self.mapper_steps = 0
        self.mapper_seconds = 0.0
        self.wait_seconds = 0.0
        self.lags: list[int] = []           # per tracked frame: its index minus the newest frame of its map version
        self.lag_keyframes: list[int] = []  # ... the keyframes between them (tracked, not yet in that version)
        self.num_added = self.num_pruned = 0
        self.densified_between = 0          # frames between keyframes densified from (live.densify_between)
        self._left_map = -1                 # newest frame tracked while the map covered < live.hurry_coverage
        self.hurried = 0                    # keyframe steps ended early for it
        # Loop closure (splat_core/loop/) runs in this mapper thread after a keyframe; while it runs the
        # tracker does not wait for the map (a loop never stalls tracking), and its pose edits happen
        # under _poses, which the tracker holds while it tracks one frame; the moved map is published
        # before _poses is released (so no frame is tracked against a map older than the poses it is
        # appended to; the seam's re-mapping comes in the next version).
        self._poses = threading.Lock()
        self._closing_loop = False
        self._batch_newest = self._mapped   # newest frame of the batch the mapper is working on
        self._settled = self._mapped        # newest frame whose mapper step (loop closure included) is done
        self._new_loops: list = []           # LoopRecords closed since the tracker last took them (FrameResult.loops)
        # live.checkpoint published: tracking states of frames not yet settled, the checkpoint callback
        self._tracking_states: dict[int, tuple[str, str]] = {}
        self._snapshot_callback = None
        self.snapshots = 0
        slam.publish(self._mapped)          # before the mapper starts: readers always find a version
        self._thread: threading.Thread | None = None    # started by the first frame

    def load_state(self, arrays: dict, keyframe_file) -> None:
        """Resume: SplaTAM's state from a checkpoint, every frame in it mapped and published."""
        if self._thread is not None:
            raise RuntimeError("load_state: the live engine has started")
        super().load_state(arrays, keyframe_file)
        self._handed = self._mapped = self._settled = self._batch_newest = self.slam.frames_tracked - 1
        self.slam.publish(self._mapped)

    def _start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run_mapper, name="slam-mapper", daemon=True)
            self._thread.start()

    @contextlib.contextmanager
    def _correction_lock(self):
        """A loop correction's lock: holds the poses, and publishes the map the correction moved
        before releasing them."""
        with self._poses:
            yield
            self.slam.publish(self._batch_newest)

    # ------------------------------------------------------------------ the tracker's side
    def process(self, frame: Frame, w2c_given=None) -> FrameResult:
        self._start()
        t = self.slam.frames_tracked
        waited = self._wait_for_map(t)
        start = time.perf_counter()
        version, t, w2c, tracked = self._track(frame, w2c_given, self._mapper_behind(t))
        lost = self.slam.lost_tracking.reason
        if self.config.wait and lost(t) is not None and any(lost(k) is None for k in range(version.frame_index + 1, t)):
            # Lost against a map that lacks frames tracked before this one: a jump into what those
            # frames saw finds no map there yet. Wait until everything handed over is mapped and track
            # once more (the sequential engine always has it); only a lost frame ever waits so.
            self.slam.retract(t)
            waited += self._wait_for_map(t, max_lag=0)
            start = time.perf_counter()
            version, t, w2c, tracked = self._track(frame, w2c_given, self._mapper_behind(t))
        if self.config.checkpoint == "published":
            with self._cond:
                self._tracking_states[t] = self.slam.tracking_state()
        if t > 0:                 # the mapper's lag behind this frame's map version (frame 0 has no map)
            self.lags.append(t - version.frame_index)
            self.lag_keyframes.append(sum(self.slam.is_keyframe(k) for k in range(version.frame_index + 1, t)))
        with self._cond:
            loops, self._new_loops = self._new_loops, []
        # Mapped later in the mapper thread (not a lost frame); "mapping" time: this frame's wait for the map.
        result = self.slam.result(frame, t, w2c, tracked, MapStats(), len(version), time.perf_counter() - start,
                                  waited, map_version=version.number, loops=loops)
        if self.paced and result.tracking_coverage is not None and \
                result.tracking_coverage < (self.config.hurry_coverage or 0):
            self._left_map = t
        with self._cond:
            self._pending.append((t, frame, w2c))
            self._handed = t
            self._cond.notify_all()
        return result

    def _track(self, frame: Frame, w2c_given, defer_keyframe: bool = False):
        """(the map version, frame index, w2c, tracker result) of the next frame tracked against the
        newest published map, under the pose lock."""
        with self._poses:
            version = self.slam.latest_version()
            return (version, *self.slam.track(frame, version.gaussians, w2c_given, defer_keyframe))

    def _mapper_behind(self, t: int) -> bool:
        """live.pace_keyframes: frame t may not become a keyframe now (a due one is deferred to the
        frames after it): that many keyframes handed over are not in the map yet. Never waits."""
        if not self.paced or t == 0:
            return False
        with self._cond:
            mapped = self._mapped
        return sum(self.slam.is_keyframe(k) for k in range(mapped + 1, t)) >= self.config.pace_keyframes

    def map_version(self) -> MapVersion:
        """The newest version the mapper published (safe to read from any thread)."""
        return self.slam.latest_version()

    def stats(self) -> dict:
        lags = dict(lag_frames_median=float(np.median(self.lags)), lag_frames_max=int(max(self.lags)),
                    lag_keyframes_median=float(np.median(self.lag_keyframes)),
                    lag_keyframes_max=int(max(self.lag_keyframes))) if self.lags else {}
        marks = self.slam.keyframe_marks
        deferred = dict(keyframes_deferred=sum(1 for k in range(1, len(marks)) if marks[k - 1] != DEFERRED == marks[k]),
                        frames_keyframe_owed=sum(m == DEFERRED for m in marks))
        return dict(live=dict(max_lag=self.config.max_lag, wait=self.config.wait, mapper_steps=self.mapper_steps,
                              pace_keyframes=self.config.pace_keyframes if self.paced else None, **deferred,
                              mapper_seconds=self.mapper_seconds, tracker_wait_seconds=self.wait_seconds,
                              gaussians_added=self.num_added, gaussians_pruned=self.num_pruned,
                              densified_between=self.densified_between, hurried_steps=self.hurried, **lags))

    def _wait_for_map(self, t: int, max_lag: int | None = None) -> float:
        """Block while the map is too far behind frame t (the policy above; `max_lag` instead of the
        configured one); returns seconds waited."""
        start = time.perf_counter()
        if max_lag is None and not self.config.wait:
            # only frame 0 must be in the map (nothing to track against before), and at most
            # live.max_keyframe_lag keyframes handed over may be missing from it
            need, keyframe_lag = 0, self.config.max_keyframe_lag
        else:
            need, keyframe_lag = max(0, t - 1 - (self.config.max_lag if max_lag is None else max_lag)), None

        def behind() -> bool:
            if self._mapped < need:
                return True
            return keyframe_lag is not None and \
                sum(self.slam.is_keyframe(k) for k in range(self._mapped + 1, t)) > keyframe_lag
        with self._cond:
            while t > 0 and behind() and self.error is None and not self._closing_loop:
                self._cond.wait(0.5)
            self._raise()
        waited = time.perf_counter() - start
        self.wait_seconds += waited
        return waited

    def request_snapshot(self, callback) -> None:
        """live.checkpoint published: the mapper calls callback(arrays, m) in its own thread after
        its next step, with SplaTAM's state at frame m, the newest frame it has settled (every frame
        up to m mapped or, live.map keyframes, passed over); the tracker goes on meanwhile. A
        request not yet served is replaced by a newer one."""
        with self._cond:
            self._snapshot_callback = callback
            self._cond.notify_all()

    def _snapshot_if_wanted(self, m: int) -> None:
        """In the mapper thread, between steps (the map, keyframes and mapper state are its own)."""
        with self._cond:
            callback, self._snapshot_callback = self._snapshot_callback, None
            tracking_state = self._tracking_states.get(m)
            for k in [k for k in self._tracking_states if k < m]:
                del self._tracking_states[k]
        if callback is None:
            return
        with self._poses:               # loop corrections and lost-frame fills edit poses under it
            w2cs = list(self.slam.w2cs[:m + 1])
        callback(self.slam.state_arrays(w2cs=w2cs, tracking_state=tracking_state), m)
        self.snapshots += 1

    def drain(self) -> None:
        """Wait until every frame handed over is mapped and published."""
        with self._cond:
            while self._settled < self._handed and self.error is None:
                self._cond.wait(0.5)
            self._raise()
        self.slam.latest_version()      # CUDA: the caller's stream waits for the mapper's last step

    def close(self) -> None:
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join()
        self._raise()

    def _raise(self) -> None:
        if self.error is not None:
            raise RuntimeError(f"the mapper thread failed: {type(self.error).__name__}: {self.error}") from self.error

    # ------------------------------------------------------------------ the mapper thread
    def _run_mapper(self) -> None:
        try:
            with mapper_stream(self.slam.device):
                while True:
                    with self._cond:
                        while not self._pending and not self._closing:
                            self._cond.wait(0.5)
                        if not self._pending:
                            return
                        batch = list(self._pending)
                        self._pending.clear()
                    self._map(batch)
        except BaseException as e:       # reported to the tracker at its next call
            with self._cond:
                self.error = e
                self._cond.notify_all()

    def _map(self, batch: list) -> None:
        start = time.perf_counter()
        slam = self.slam
        newest = self._batch_newest = batch[-1][0]
        between = None
        if self.config.map == "keyframes" and not self.config.wait:     # only keyframes (frame 0 is one)
            between = batch[-1] if self.config.densify_between and not slam.is_keyframe(newest) else None
            batch = [b for b in batch if slam.is_keyframe(b[0])]
            if not batch:
                if between is not None and self._densify_between(*between):
                    self._published(newest, newest)
                with self._cond:
                    self._mapped = self._settled = newest
                    self._cond.notify_all()
                self._snapshot_if_wanted(newest)
                return
            mapped_until = self._batch_newest = batch[-1][0]
            # every keyframe of the batch optimised over its own window (a starved mapper that finds
            # several would otherwise give all but the newest no optimisation at all)
            every = True
        else:
            mapped_until, every = newest, False
        for t, frame, w2c in batch:
            if t == mapped_until or slam.is_keyframe(t):
                # live.publish_densified: the keyframe's new Gaussians reach the tracker before its
                # optimisation (the keyframe still counts as unmapped: pace_keyframes, drain)
                early = (lambda t=t: slam.publish(t)) if self.config.publish_densified else None
                stats = slam.map_frame(frame, w2c, t, optimise=(t == mapped_until or every), densified=early,
                                       stop=lambda done, t=t: self._stop(done, t))
                self.num_added += stats.added
                self.num_pruned += stats.pruned
        if every and between is not None and self._densify_between(*between):
            mapped_until = newest
        # The batch's map is published before loop closure runs: the tracker does not wait while a
        # loop closes, so it must find this batch's frames in the map (the first frame's above all).
        self._published(newest, mapped_until)
        # every keyframe of the batch, oldest first: which keyframes are checked for loops does not
        # depend on how many frames the tracker handed over meanwhile
        closed = []
        for t in [t for t, _, _ in batch if slam.loop_closure is not None and slam.is_keyframe(t)]:
            closed += self._close_loops(t)
        if closed:
            with self._cond:
                self._new_loops.extend(closed)
            self._published(newest, mapped_until)       # the seams re-mapped after the corrections
        self.mapper_steps += 1
        self.mapper_seconds += time.perf_counter() - start
        with self._cond:
            self._settled = newest          # its loop closure done too: drain() may return
            self._cond.notify_all()
        self._snapshot_if_wanted(newest)

    def _stop(self, done: int, t: int) -> bool:
        """live.hurry_coverage: keyframe t's step ends after hurry_iterations once a frame after t
        was tracked against a map that covered too little of it (the camera is leaving the map)."""
        self.hurried += (stop := self._left_map > t and done >= self.config.hurry_iterations)
        return stop

    def _densify_between(self, t: int, frame, w2c) -> bool:
        """live.densify_between: new Gaussians from frame t, a frame between keyframes (no optimisation;
        a lost frame adds nothing). Without them the tracker aligns the next frames against a map that
        lacks what came into view since the last keyframe, and the alignment's pose and the tracking
        loss both drift toward what the map holds: on the synthetic corridor, looking down it, each
        frame 0.3-2 cm off from a perfect prediction, against 0.1 cm with these Gaussians
        (docs/benchmarks.md, "Long runs"). True when any were added."""
        stats = self.slam.map_frame(frame, w2c, t, optimise=False)
        self.num_added += stats.added
        self.densified_between += 1
        return stats.added > 0

    def _published(self, newest: int, mapped_until: int | None = None) -> None:
        """Publish the map; `mapped_until`: the newest frame in it (live.map keyframes: the newest
        keyframe; the frames after it up to `newest` are settled, not mapped)."""
        self.slam.publish(newest if mapped_until is None else mapped_until)
        with self._cond:
            self._mapped = newest
            self._cond.notify_all()

    def _close_loops(self, t: int) -> list:
        """Loop closure after keyframe t (the tracker runs on meanwhile); frames handed over and not
        yet mapped get their corrected poses."""
        with self._cond:
            self._closing_loop = True
            self._cond.notify_all()
        try:
            loops = self.slam.close_loops(t, self._correction_lock)
            if loops:
                with self._poses, self._cond:
                    self._pending = deque((k, f, self.slam.w2cs[k]) for k, f, _ in self._pending)
            return loops
        finally:
            with self._cond:
                self._closing_loop = False
                self._cond.notify_all()
