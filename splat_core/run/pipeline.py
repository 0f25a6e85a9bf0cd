"""The pipeline around the algorithm: frames in, the engine, checkpoints, evaluation, the run folder.

    pipe = Pipeline(open_input(path), load_config("cpu"), out_dir=Path("run"))
    while pipe.step() is not None: ...
    metrics = pipe.finish()

Used by `splatam run` (with a progress bar) and by the viewer's worker thread (one step at a
time, so it can pause). `step` reads a frame from the feed, hands it to the engine (sequential or
live: one interface, engines.py) and records what happened; `finish` evaluates and writes the
run folder (run_folder.py).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Protocol

import numpy as np

from ..camera import Intrinsics, invert_pose, is_finite_pose
from ..config import Config
from ..errors import InputError
from ..frame import Frame
from ..io.source import FrameSource
from ..keyframes import Keyframe
from ..memory import release_free_memory
from ..registration_estimate import register_from_estimate
from ..slam import FrameResult, MapVersion, SplaTAM
from .engines import ENGINES, make_engine
from .frame_feed import FrameFeed, input_record, resolve_device
from .report import ate_cm, evaluate, summary
from .resolution import source_working_size
from .pose_arrays import InverseTrajectory, ReferenceWorld
from .run_folder import RunFolder

RELEASE_MEMORY_EVERY = 10      # frames between returns of freed heap memory to the system (memory.py)


class SlamRun(Protocol):
    """What the app (the worker thread, `splatam run`) may use of a run: nothing else.

    `step()` and `finish()` are called by one thread only; `map_version()`, `keyframes()` and the
    trajectory getters may be read between steps by that thread (the live engine's versions are
    safe to read from any thread)."""

    total: int | None           # frames to process (None: a live stream of unknown length)
    out_dir: Path | None
    config: Config
    intrinsics: Intrinsics      # working resolution
    records: list[dict]         # per processed frame: wall_seconds, tracking_loss, ...
    skipped: list[dict]         # bad frames skipped: source_index, reason
    lost: list[dict]            # frames where tracking was lost (pose held, not mapped): index, source_index, reason
    streaming: bool             # the source is a LiveSource (a stream, --realtime): source.received / dropped

    def step(self) -> FrameResult | None: ...
    def finish(self) -> dict: ...
    def map_version(self) -> MapVersion: ...
    def loops(self) -> tuple | None:
        """The loops closed so far (LoopRecords, oldest first); None: loop closure is off."""
        return self.engine.loops()

    def keyframes(self) -> list[Keyframe]: ...
    def estimated_c2w(self) -> list[np.ndarray]: ...
    def estimated_c2w_array(self) -> np.ndarray: ...
    def reference_c2w(self) -> list[np.ndarray | None] | None: ...
    def reference_c2w_array(self) -> np.ndarray | None: ...
    def ate_cm(self) -> float | None: ...


class Pipeline:
    def __init__(self, source: FrameSource, config: Config, out_dir=None, *, device="auto",
                 max_frames: int | None = None, stride: int = 1, resume: bool = False,
                 engine: str = "sequential"):
        if stride < 1:
            raise InputError(f"--stride {stride}: expected a positive integer")
        if engine not in ENGINES:
            raise InputError(f"--engine {engine}: expected one of {', '.join(ENGINES)}")
        self.engine_name = engine
        self.notes: list[str] = []             # adjustments made for this input, shown by the CLI
        if not source.registered and config.estimate_registration:
            note = register_from_estimate(source)       # colour registered to depth when read, from now on
            if note:
                self.notes.append(note)
        if not source.registered and (config.tracking.color_weight or config.tracking.align.color_weight):
            # Colour a few pixels off the depth pulls the pose away from where the depth puts it
            # (7-Scenes: 4.0-4.5 cm ATE with colour, 2.5 cm without; docs/history/2026-11-23-cpu-preset-tracking.md).
            config = dataclasses.replace(config, tracking=dataclasses.replace(
                config.tracking, color_weight=0.0, align=dataclasses.replace(config.tracking.align, color_weight=0.0)))
            self.notes.append("colour and depth are not registered (camera file): tracking uses depth alone")
        self.source, self.config = source, config
        self.folder = RunFolder(out_dir) if out_dir is not None else None
        self.device = resolve_device(device)
        if getattr(source, "live", False) and (stride != 1 or resume):
            raise InputError("--stride and --resume do not apply to a live stream (rerun its capture folder instead)")
        # The preset's resolution on this capture's shape (aspect kept; resolution.py).
        self.intrinsics = source.intrinsics.scaled(*source_working_size(source, config))
        self.feed = FrameFeed(source, self.intrinsics, config, max_frames=max_frames, stride=stride)
        slam = SplaTAM(config, self.intrinsics, device=self.device, total_frames=self.total, stride=stride)
        self.engine = make_engine(engine, slam, config, live_source=self.streaming)
        self.records: list[dict] = []          # per-frame numbers kept for metrics.json and resume
        self._lost_scan: tuple = (self.records, 0, [])     # `lost`: (records read, how many, lost found)
        self._feed_marks: list[tuple[int, int]] = []    # per frame: the feed's cursor and skipped count after it
        self.references: list[np.ndarray | None] = []
        self._inverses, self._reference_world_poses = InverseTrajectory(), ReferenceWorld()   # each pose once
        self.started = time.perf_counter()
        self._last_step = None
        self._last_cpu = None                   # the process's CPU time (all threads) at _last_step
        if resume and self.folder is not None and not self.folder.has_checkpoint():
            self.warn(f"{self.folder.checkpoint_dir}: no checkpoint written yet; starting from the first frame")
            resume = False
        if resume:
            self._resume()
        elif self.folder is not None:
            self.engine.attach_keyframes(self.folder.keyframe_file)

    # ------------------------------------------------------------------ what the feed knows
    out_dir = property(lambda self: self.folder.path if self.folder is not None else None)
    total = property(lambda self: self.feed.total)
    indices = property(lambda self: self.feed.indices)
    cursor = property(lambda self: self.feed.cursor)
    skipped = property(lambda self: self.feed.skipped)
    streaming = property(lambda self: self.feed.streaming)

    @property
    def warn(self):
        return self.feed.warn

    @warn.setter
    def warn(self, function) -> None:
        self.feed.warn = function

    def loops(self) -> tuple | None:
        """The loops closed so far (LoopRecords, oldest first); None: loop closure is off."""
        return self.engine.loops()

    def keyframes(self) -> list[Keyframe]:
        return self.engine.keyframes()

    def map_version(self) -> MapVersion:
        """The newest map that may be read from any thread."""
        return self.engine.map_version()

    def frame(self, k: int) -> Frame:
        """Processed frame k at the working resolution, depth cut at max_depth."""
        return self.frame_at(int(self.records[k]["source_index"]))

    def frame_at(self, i: int, raw: Frame | None = None) -> Frame:
        return self.feed.frame_at(i, raw)

    # ------------------------------------------------------------------ one frame
    def step(self) -> FrameResult | None:
        k = len(self.records)
        frame = self.feed.next(started=bool(self.records), check=self._check_reference)
        if frame is None:
            return None
        given = None
        if self.config.tracking.use_reference_poses:
            given = invert_pose(self._reference_world(frame.c2w_ref, frame.c2w_ref if k == 0 else self.references[0]))
        begun, cpu_begun = time.perf_counter(), time.process_time()
        result = self.engine.process(frame, given)
        if k == 0 and self.streaming:
            # A live source's clock runs from its second frame (io/playback.py): the first is
            # mapped before it is asked for (the live engine would wait for that anyway).
            self.engine.drain()
        result.frame = frame
        now = time.perf_counter()   # wall time since the last frame (the first: its own processing)
        wall = now - self._last_step if self._last_step is not None else \
            now - begun if self.streaming else result.tracking_seconds + result.mapping_seconds
        cpu_now = time.process_time()   # CPU seconds of every thread (the live mapper's too), same span
        cpu = cpu_now - (self._last_cpu if self._last_cpu is not None else cpu_begun)
        self._last_step, self._last_cpu = now, cpu_now
        self.references.append(frame.c2w_ref)
        self._feed_marks.append((self.cursor, len(self.skipped)))
        self.records.append(dict(
            index=k, source_index=frame.index, timestamp=frame.timestamp, wall_seconds=wall, cpu_seconds=cpu,
            tracking_seconds=result.tracking_seconds, mapping_seconds=result.mapping_seconds,
            tracking_loss=result.tracking_loss, tracking_iterations=result.tracking_iterations,
            tracking_coverage=result.tracking_coverage,
            tracking_start=result.tracking_start, num_gaussians=result.num_gaussians, num_added=result.num_added, num_pruned=result.num_pruned,
            is_keyframe=result.is_keyframe, lost=result.lost))
        self._report_lost(result)
        if (k + 1) % RELEASE_MEMORY_EVERY == 0:
            release_free_memory()
        every = self.config.checkpoint_every
        if self.folder is not None and every and (k + 1) % every == 0 and (self.total is None or k + 1 < self.total):
            if self.engine_name == "live" and self.config.live.checkpoint == "published":
                self.engine.request_snapshot(self._save_published)      # saved by the mapper: no stall
            else:
                self.save_checkpoint()
        return result

    def _check_reference(self, frame: Frame, i: int) -> None:
        if self.config.tracking.use_reference_poses and not (
                is_finite_pose(frame.c2w_ref) and (not self.references or is_finite_pose(self.references[0]))):
            raise InputError(f"{self.feed.where} frame {i}: no finite reference pose (tracking.use_reference_poses)")

    @property
    def lost(self) -> list[dict]:
        """The lost frames' (index, source_index, reason); each record is read once (the viewer's
        worker asks after every frame): only those appended since the last call, unless the records
        are a new list (a resume)."""
        records, scanned, found = self._lost_scan
        if records is not self.records or scanned > len(self.records):
            records, scanned, found = self.records, 0, []
        found.extend(dict(index=r["index"], source_index=r["source_index"], reason=r["lost"])
                     for r in records[scanned:] if r.get("lost"))
        self._lost_scan = (records, len(records), found)
        return list(found)

    def _report_lost(self, result: FrameResult) -> None:
        """One warning when tracking is lost and one when it is back (not one per lost frame)."""
        before = self.records[-2].get("lost") if len(self.records) > 1 else None
        if result.lost and not before:
            self.warn(f"tracking lost at frame {result.index} (capture frame {result.source_index}): {result.lost}; "
                      "relocalising against the keyframes (lost frames are not mapped)")
        elif before and not result.lost:
            run = next((k for k in range(len(self.records) - 2, -1, -1) if not self.records[k].get("lost")), -1)
            self.warn(f"tracking recovered at frame {result.index} after {len(self.records) - 2 - run} lost frame(s)")

    # ------------------------------------------------------------------ trajectories
    @staticmethod
    def _reference_world(c2w_ref, c2w_ref0):
        if not (is_finite_pose(c2w_ref) and is_finite_pose(c2w_ref0)):
            return None
        return invert_pose(c2w_ref0) @ c2w_ref

    def estimated_c2w(self) -> list[np.ndarray]:
        return list(self.estimated_c2w_array())

    def estimated_c2w_array(self) -> np.ndarray:
        """estimated_c2w as one (n, 4, 4) array (a new one each call; only new or moved poses inverted)."""
        return self._inverses(self.engine.trajectory())

    def has_reference(self) -> bool:
        return any(is_finite_pose(r) for r in self.references)

    def reference_c2w(self) -> list[np.ndarray | None] | None:
        """Reference poses in the SLAM world (first frame's camera), or None without any."""
        world = self._world_references()
        return None if world is None else list(world.poses)

    def reference_c2w_array(self) -> np.ndarray | None:
        """reference_c2w as one (n, 4, 4) array, NaN rows where a frame has none (a new one each call)."""
        world = self._world_references()
        return None if world is None else world.rows.copy()

    def _world_references(self) -> ReferenceWorld | None:
        """The reference poses in the SLAM world, the frames added since the last call converted
        (None without any)."""
        if not self.has_reference():
            return None
        self._reference_world_poses.update(self.references, self._reference_world)
        return self._reference_world_poses

    def ate_cm(self) -> float | None:
        return ate_cm(self.estimated_c2w_array(), self.reference_c2w_array())

    # ------------------------------------------------------------------ checkpoints
    def _meta(self, frames: int | None = None) -> dict:
        """The checkpoint's meta.json; `frames`: as it stood after that many frames (a live
        checkpoint of what the mapper has published, `_save_published`)."""
        if frames is None:
            n, cursor, skipped = len(self.records), self.cursor, self.skipped
        else:
            n, (cursor, skips) = frames, self._feed_marks[frames - 1]
            skipped = self.skipped[:skips]
        return dict(frames_done=n, total=self.total, indices=self.indices, engine=self.engine_name,
                    cursor=cursor, skipped=skipped,
                    records=self.records[:n], references=[None if r is None else np.asarray(r).tolist()
                                                          for r in self.references[:n]],
                    config=self.config.to_dict(), intrinsics=self.intrinsics.to_dict(),
                    input=input_record(self.source), elapsed_seconds=time.perf_counter() - self.started)

    def save_checkpoint(self) -> None:
        self.folder.save_checkpoint(self.engine.state_arrays(), self._meta())

    def _save_published(self, arrays: dict, m: int) -> None:
        """live.checkpoint published: called in the live mapper's thread with SplaTAM's state at frame
        m (the newest it settled); the checkpoint holds frames 0..m, a resume goes on from m + 1."""
        self.folder.save_checkpoint(arrays, self._meta(frames=m + 1))

    def _resume(self) -> None:
        ckpt = self.folder.load_checkpoint()
        where = self.folder.path
        if ckpt.meta.get("indices") != self.indices:
            raise InputError(f"{where}: the checkpoint was made with other frames "
                             "(--input/--stride/--max-frames must match the original run)")
        if ckpt.meta.get("config") != self.config.to_dict():
            raise InputError(f"{where}: the checkpoint was made with another config")
        if ckpt.meta.get("engine", "sequential") != self.engine_name:
            raise InputError(f"{where}: the checkpoint was made with --engine {ckpt.meta.get('engine')}")
        self.engine.load_state(ckpt.arrays, self.folder.keyframe_file)
        self.records = list(ckpt.meta["records"])
        self.feed.load_state(ckpt.meta, len(self.records))
        self._feed_marks = [(self.feed.cursor, len(self.feed.skipped))] * len(self.records)
        self.references = [None if r is None else np.array(r) for r in ckpt.meta["references"]]
        self.started -= float(ckpt.meta.get("elapsed_seconds", 0.0))

    # ------------------------------------------------------------------ results
    def evaluate(self) -> dict:
        """Render metrics at the estimated poses on frame 0 and every eval_every-th frame."""
        return evaluate(self.engine.render, self.engine.trajectory(), self.records, self.frame, self.config.eval_every)

    def metrics(self) -> dict:
        out = summary(self)
        out.update(self.engine.stats())
        out.update(self.engine.loop_figures() or {})
        out.update(self.evaluate())
        out["per_frame"] = self.records
        return out

    def finish(self) -> dict:
        """Compute metrics and write the run folder (each file atomically)."""
        self.engine.drain()
        self.engine.close()
        finished = self.engine.finish_map()      # the end-of-run hole fill and colour fit (SplaTAM.finish)
        # Time to the end of the run counts: the live engine's last frames are mapped only now, and
        # the map is finished (its colours fitted) only now.
        if self.records and self._last_step is not None:
            self.records[-1]["wall_seconds"] += time.perf_counter() - self._last_step
            self.records[-1]["cpu_seconds"] = self.records[-1].get("cpu_seconds", 0.0) + time.process_time() - self._last_cpu
            self._last_step = self._last_cpu = None
        result = self.metrics()
        result.update(finished)                  # final_hole_fill, final_color_fit: each with its seconds
        if self.folder is not None:
            comments = {r["index"]: f"tracking lost at frame {r['index']} (capture frame {r['source_index']}): "
                        f"{r['reason']}; the pose below is not tracked (interpolated between the tracked frames on "
                        "either side, or held at the last tracked pose when the run ended lost)" for r in self.lost}
            self.folder.write_results([r["timestamp"] for r in self.records], self.estimated_c2w(),
                                      self.engine.map_arrays(), self.config.to_dict(), result, comments=comments)
            self.save_checkpoint()
        return result
