"""SlamWorker: runs the SLAM pipeline in a thread and publishes MapSnapshots.

The worker owns the pipeline: it is the only thread that calls `step()` or reads the live
optimiser tensors. After each frame it publishes an immutable snapshot (latest only) and
hands the frame to the live panel's renderer (live_preview.py, its own thread). It obeys
pause / resume / step one frame / stop between frames, never calls viser, and when the sequence
ends it writes the run folder with `pipeline.finish()` (as `splatam run` does) and stays alive
only as a last snapshot.
"""

from __future__ import annotations

import logging
import operator
import threading
import time
import traceback

import numpy as np

from splat_core.metrics import RunningAte, psnr
from splat_core.run.pose_arrays import GrowingArray

from .live_preview import LivePreview
from .snapshot import (HISTORY_KEYS, LIVE_TILE_WIDTH, KeyframeView, LiveView, MapSnapshot, VersionArrays,
                       empty_gaussians, freeze_gaussians, frozen, make_thumbnail)

log = logging.getLogger(__name__)


class SlamWorker(threading.Thread):
    """Runs `pipeline` frame by frame; `latest()` returns the newest MapSnapshot.

    map_interval_s: the Gaussian arrays are copied at most this often (and on every keyframe,
    pause and at the end); the other snapshot fields are refreshed after every frame.
    live_render: render the map at the tracked pose (colour, depth, silhouette) for the panel,
    at most `live_max_width` pixels wide (the panel's tile width: the PSNR beside it is of that
    size too), in a LivePreview thread: at most every `live_interval_s`
    and at most `live_duty` of one core (the viewer shows one update a second while SLAM runs,
    app/viewer/app.py; a render per frame, or one in the SLAM thread, would only slow SLAM
    down). Between those the panel keeps the last rendered frame, so image and render always
    belong together; a pause and the run's end show the last frame's render.
    prepare: called as `prepare(report)` in the thread before the first frame (the viewer compiles
    the CPU kernels there on a first run: app.warmup.KernelCompile.run); `report(text)` publishes
    `text` as the snapshot's message, which the page shows while there is no map.
    """

    def __init__(self, pipeline, *, start_paused: bool = False, live_render: bool = True,
                 render_backend: str = "auto", live_max_width: int = LIVE_TILE_WIDTH,
                 map_interval_s: float = 0.4, out_dir=None, frame_delay_s: float = 0.0,
                 live_interval_s: float = 1.0, live_duty: float = 0.25, prepare=None):
        super().__init__(name="slam-worker", daemon=True)
        self.pipeline = pipeline
        self.prepare = prepare
        self.live_render = live_render
        self.render_backend = render_backend
        self.live_max_width = live_max_width
        self.map_interval_s = map_interval_s
        self.live_interval_s = live_interval_s
        self.live_duty = live_duty
        self._preview: LivePreview | None = None      # made when the thread starts
        self.frame_delay_s = frame_delay_s
        self.out_dir = out_dir if out_dir is not None else getattr(pipeline, "out_dir", None)
        self.metrics: dict | None = None
        self.error: BaseException | None = None

        self._cond = threading.Condition()
        self._paused = start_paused
        self._steps_requested = 0
        self._stop_requested = False
        self._state = "paused" if start_paused else "starting"
        self._snapshot: MapSnapshot | None = None
        self._version = 0
        self._map_version = 0
        self._map_arrays = freeze_gaussians(empty_gaussians())
        self._map_copied_at = -1e9
        self._keyframe_views: dict[int, tuple] = {}     # frame -> (the w2c array it was made from, KeyframeView)
        self._keyframes_seen: tuple | None = None       # (keyframes, their w2c arrays, views) of the last _keyframes()
        self._ate = RunningAte()                        # the history's ATE, frame by frame
        self._history = {k: GrowingArray(()) for k in HISTORY_KEYS}   # one entry a frame
        self._timestamps = GrowingArray(())
        self._live: LiveView | None = None
        self._last_frame_index = -1
        self._publish(force_map=True)

    # ------------------------------------------------------------------ controls (any thread)
    def pause(self) -> None:
        with self._cond:
            self._paused = True
            self._cond.notify_all()

    def resume(self) -> None:
        with self._cond:
            self._paused = False
            self._cond.notify_all()

    def step_once(self) -> None:
        """Process exactly one more frame, then stay paused."""
        with self._cond:
            self._paused = True
            self._steps_requested += 1
            self._cond.notify_all()

    def stop(self, join_timeout: float | None = None) -> None:
        """Stop after the current frame; the run folder is still written (a partial run)."""
        with self._cond:
            self._stop_requested = True
            self._cond.notify_all()
        if join_timeout is not None and self.is_alive():
            self.join(join_timeout)

    @property
    def paused(self) -> bool:
        return self._paused

    @property
    def state(self) -> str:
        return self._state

    def latest(self) -> MapSnapshot | None:
        return self._snapshot

    def wait_for(self, predicate, timeout: float = 10.0) -> MapSnapshot | None:
        """Block until predicate(latest snapshot) is true (tests and the benchmark use this)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while not predicate(self._snapshot):
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(min(left, 0.2))
            return self._snapshot

    # ------------------------------------------------------------------ the thread
    def run(self) -> None:
        if self.live_render:
            self._preview = LivePreview(self._render_live, self.live_interval_s, self.live_duty)
        try:
            if self.prepare is not None:
                self.prepare(lambda text: self._publish(message=text))
                self._publish(message="")
            while True:
                with self._cond:
                    if not self._stop_requested and self._paused and self._steps_requested == 0:
                        self._state = "paused"
                        self._show_last_render()
                        self._publish(force_map=True)
                    while not self._stop_requested and self._paused and self._steps_requested == 0:
                        self._cond.wait(0.5)
                    if self._stop_requested:
                        break
                    if self._steps_requested:
                        self._steps_requested -= 1
                    self._state = "running" if not self._paused else "paused"
                result = self.pipeline.step()
                if result is None:
                    break
                self._after_frame(result)
                if self.frame_delay_s:
                    time.sleep(self.frame_delay_s)
            stopped = self._stop_requested
            self._show_last_render()
            self.metrics = self.pipeline.finish()
            self._state = "stopped" if stopped else "finished"
            message = f"run written to {self.out_dir}" if self.out_dir else "run complete"
            self._publish(force_map=True, message=message)
        except BaseException as e:  # the viewer stays up and shows the error
            self.error = e
            log.error("SLAM worker failed:\n%s", traceback.format_exc())
            self._state = "error"
            self._publish(force_map=False, message=f"SLAM failed: {type(e).__name__}: {e}")
        finally:
            if self._preview is not None:
                self._preview.close()

    def _show_last_render(self) -> None:
        """The panel shows the newest frame's render now (a pause, the run's end)."""
        if self._preview is not None:
            self._preview.flush()
            self._show(self._preview.latest())

    def _show(self, live: LiveView | None) -> None:
        """Make `live` the panel's frame; its render's PSNR goes into the plot at its own frame
        (a render made in the preview thread arrives after later frames were processed)."""
        if live is None or live is self._live:
            return
        self._live = live
        at = np.flatnonzero(self._history["frame"].view() == live.frame_index)
        if live.psnr is not None and len(at):
            self._history["psnr"].view()[at[-1]] = float(live.psnr)

    def _after_frame(self, r) -> None:
        pipe = self.pipeline
        self._last_frame_index = int(r.index)
        self._timestamps.append(float(r.timestamp))
        seconds = float(pipe.records[-1]["wall_seconds"])
        poses = pipe.estimated_c2w_array(), pipe.reference_c2w_array()   # each pose converted once
        ate = None if poses[1] is None else self._ate(*poses)      # the sums of new or moved pairs only
        ate = None if ate is None else 100.0 * ate
        for key, value in (("frame", r.index), ("tracking_loss", r.tracking_loss), ("ate_cm", ate),
                           ("seconds", seconds), ("psnr", None), ("num_gaussians", r.num_gaussians)):
            self._history[key].append(np.nan if value is None else float(value))
        if self._preview is None:
            self._show(LiveView(int(r.index), frozen(r.frame.color), frozen(r.frame.depth)))
        else:
            self._preview.offer(r, pipe.map_version())
            self._show(self._preview.latest())
        self._publish(force_map=bool(r.is_keyframe), poses=poses)

    def _render_live(self, r, map_version) -> LiveView:
        """(In the LivePreview thread.) `map_version`: a published map, never a tensor the mapper
        is stepping."""
        frame = r.frame
        color, depth = frame.color, frame.depth
        try:
            import torch

            from splat_core.render import Renderer

            intr = frame.intrinsics
            if intr.width > self.live_max_width:
                w = self.live_max_width
                intr = intr.scaled(w, max(1, int(round(intr.height * w / intr.width))))
            renderer = Renderer(self.pipeline.config.near_plane, self.render_backend)
            with torch.no_grad():
                out = renderer.render_visible(map_version.gaussians, intr, r.w2c)
            rc, rd, ra = (t.detach().cpu().numpy() for t in out)
            import cv2

            small = cv2.resize(color, (intr.width, intr.height), interpolation=cv2.INTER_AREA) \
                if intr.width != frame.width else color
            return LiveView(int(r.index), frozen(color), frozen(depth), frozen(rc), frozen(rd),
                            frozen(ra), psnr(rc, small))
        except Exception:  # a failed preview must never stop SLAM
            log.warning("live render failed:\n%s", traceback.format_exc())
            return LiveView(int(r.index), frozen(color), frozen(depth))

    # ------------------------------------------------------------------ snapshots
    def _keyframes(self) -> tuple:
        """A view per keyframe, made again when its pose changed (a loop correction gives a keyframe a
        new w2c array: slam.py apply_correction); the same tuple as last time while no keyframe came
        or moved, found by identity (the arrays compared are held, so no id is reused meanwhile)."""
        kfs = tuple(self.pipeline.keyframes())
        w2cs = tuple(kf.w2c for kf in kfs)
        seen = self._keyframes_seen
        if seen is not None and len(seen[0]) == len(kfs) and all(map(operator.is_, seen[0], kfs)) \
                and all(map(operator.is_, seen[1], w2cs)):
            return seen[2]
        views = []
        for kf, w2c in zip(kfs, w2cs):
            w2c_seen, view = self._keyframe_views.get(kf.frame_index, (None, None))
            if view is None or w2c is not w2c_seen:
                thumbnail = view.thumbnail if view is not None else frozen(make_thumbnail(kf.color))
                view = KeyframeView(int(kf.frame_index), frozen(np.linalg.inv(w2c)), thumbnail, kf)
                self._keyframe_views[kf.frame_index] = (w2c, view)
            views.append(view)
        self._keyframes_seen = (kfs, w2cs, tuple(views))
        return self._keyframes_seen[2]

    def _loops(self) -> tuple | None:
        """The loops of the map version shown (None: loop closure is off in this run)."""
        closure = getattr(self.pipeline.config, "loop_closure", None)
        if closure is None or not closure.enabled:
            return None
        version = getattr(self._map_arrays, "version", None)
        return tuple(getattr(version, "loops", ()) or ())

    def _publish(self, force_map: bool = False, message: str = "", poses: tuple | None = None) -> None:
        """`poses`: the pipeline's (estimated_c2w_array, reference_c2w_array) when the caller has them
        (new arrays each: the snapshot keeps them, read-only, without another copy)."""
        pipe = self.pipeline
        now = time.monotonic()
        if force_map or now - self._map_copied_at >= self.map_interval_s:
            self._map_arrays = VersionArrays(pipe.map_version())   # no copy: versions are immutable
            self._map_version += 1
            self._map_copied_at = now
        if poses is None:
            poses = ((pipe.estimated_c2w_array(), pipe.reference_c2w_array()) if self._last_frame_index >= 0
                     else (np.zeros((0, 4, 4)), None))
        est, ref = poses
        reference = ref if ref is not None and len(ref) and np.isfinite(ref).any() else None
        history = {k: frozen(v.view()) for k, v in self._history.items()}
        secs = history["seconds"]
        ate = history["ate_cm"]
        with self._cond:
            self._version += 1
            self._snapshot = MapSnapshot(
                version=self._version, state=self._state, frame_index=self._last_frame_index,
                total_frames=int(pipe.total or len(pipe.records)), map_version=self._map_version,
                gaussians=self._map_arrays,
                keyframes=self._keyframes(), intrinsics=pipe.intrinsics, near_plane=float(pipe.config.near_plane),
                timestamps=frozen(self._timestamps.view()), estimated_c2w=frozen(est, copy=False),
                reference_c2w=frozen(reference, copy=False), history=history, live=self._live,
                seconds_per_frame=float(np.nanmean(secs[-10:])) if len(secs) else None,
                ate_cm=float(ate[-1]) if len(ate) and np.isfinite(ate[-1]) else None,
                message=message, out_dir=self.out_dir,
                skipped_frames=tuple((s["source_index"], s["reason"]) for s in pipe.skipped),
                lost_frames=tuple(int(x["index"]) for x in pipe.lost), loops=self._loops(),
                received=(int(pipe.source.received), int(pipe.source.dropped)) if pipe.streaming else None,
            )
            self._cond.notify_all()
