"""The pipeline around the algorithm: reading frames, checkpoints, evaluation, run-folder outputs.

    pipe = Pipeline(open_input(path), load_config("cpu"), out_dir=Path("run"))
    while pipe.step() is not None: ...
    metrics = pipe.finish()

Used by `splatam run` (with a progress bar) and by the viewer's worker thread (one step at a
time, so it can pause). A run folder holds trajectory.txt, map.ply, metrics.json, config.yaml
and checkpoint/.
"""

from __future__ import annotations

import dataclasses
import json
import platform
import resource
import sys
import time
from pathlib import Path
from typing import Protocol

import numpy as np
import torch
import yaml

from . import metrics as M
from .camera import Intrinsics, invert_pose, is_finite_pose
from .config import Config
from .errors import InputError
from .frame import Frame, resize_frame
from .io import checkpoint
from .io.atomic import write_text_atomic
from .io.source import FrameSource
from .keyframes import KEYFRAME_FILE, Keyframe
from .live import LiveEngine
from .memory import release_free_memory
from .resolution import source_working_size
from .slam import FrameResult, MapVersion, SplaTAM

ENGINES = ("sequential", "live")


def open_input(path=None, format: str | None = None, **options) -> FrameSource:
    """A capture (folder or .r3d/.zip, format detected), the live `nerfcapture://` stream (options:
    capture_dir, idle_timeout) or, with no path, the synthetic demo scene."""
    if isinstance(path, str) and path.startswith("nerfcapture://"):
        from .io.nerfcapture_stream import NeRFCaptureStream
        return NeRFCaptureStream(url=path, **options)
    if path is None:
        from .synthetic import SyntheticSource
        return SyntheticSource(**options)
    from .io import open_capture
    return open_capture(path, format=format, **options)


def resolve_device(device: str) -> torch.device:
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA device is available to torch")
    if device not in ("cpu", "cuda"):
        raise InputError(f"--device {device}: expected auto, cpu or cuda")
    return torch.device(device)


RELEASE_MEMORY_EVERY = 10      # frames between returns of freed heap memory to the system (memory.py)

# A capture whose first this many frames are all unusable is refused as a whole (exit 2).
MAX_LEADING_BAD_FRAMES = 10


def check_frame(frame: Frame, where: str) -> None:
    if frame.color.shape[:2] != frame.depth.shape:
        raise InputError(f"{where}: colour {frame.color.shape[:2]} and depth {frame.depth.shape} sizes differ")
    if not np.all(np.isfinite(frame.depth)):
        raise InputError(f"{where}: depth has NaN or inf values")
    if not (frame.depth > 0).any():
        raise InputError(f"{where}: no valid depth in this frame")


def prepare_frame(source: FrameSource, i: int, intrinsics: Intrinsics, max_depth: float | None,
                  raw: Frame | None = None) -> Frame:
    """Capture frame i (or `raw`, that frame as received) at `intrinsics`' resolution, depth cut at
    max_depth; InputError naming the file when it is unusable."""
    frame = source.frame_at_size(i, intrinsics.width, intrinsics.height) if raw is None else raw
    name = source._name(i, "depth") if hasattr(source, "_name") else f"{getattr(source, 'path', 'input')} frame {i}"
    check_frame(frame, name)
    frame = resize_frame(frame, intrinsics.width, intrinsics.height)
    if max_depth:
        frame.depth = np.where(frame.depth <= max_depth, frame.depth, 0).astype(np.float32)
    return frame


def input_record(source: FrameSource) -> dict | None:
    """Where a run's frames came from, so `splatam refine` can re-read them (a live stream: the capture
    folder it was recorded to, whose format is detected); None for the synthetic scene."""
    if getattr(source, "path", None) is None:
        return None
    live = getattr(source, "live", False)
    return dict(path=str(Path(source.path).resolve()), format=None if live else source.format_name)


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

    def step(self) -> FrameResult | None: ...
    def finish(self) -> dict: ...
    def map_version(self) -> MapVersion: ...
    def keyframes(self) -> list[Keyframe]: ...
    def estimated_c2w(self) -> list[np.ndarray]: ...
    def reference_c2w(self) -> list[np.ndarray | None] | None: ...
    def ate_cm(self) -> float | None: ...


class Pipeline:
    def __init__(self, source: FrameSource, config: Config, out_dir=None, *, device="auto",
                 max_frames: int | None = None, stride: int = 1, resume: bool = False,
                 engine: str = "sequential"):
        if stride < 1:
            raise InputError(f"--stride {stride}: expected a positive integer")
        if engine not in ENGINES:
            raise InputError(f"--engine {engine}: expected one of {', '.join(ENGINES)}")
        self.engine = engine
        self.notes: list[str] = []             # adjustments made for this input, shown by the CLI
        if not source.registered and (config.tracking.color_weight or config.tracking.align_color_weight):
            # Colour a few pixels off the depth pulls the pose away from where the depth puts it
            # (7-Scenes: 4.0-4.5 cm ATE with colour, 2.5 cm without; README).
            config = dataclasses.replace(config, tracking=dataclasses.replace(
                config.tracking, color_weight=0.0, align_color_weight=0.0))
            self.notes.append("colour and depth are not registered (camera file): tracking uses depth alone")
        self.source, self.config = source, config
        self.out_dir = Path(out_dir) if out_dir is not None else None
        self.device = resolve_device(device)
        # A live source (`live = True`, e.g. nerfcapture://) is pulled with next_frame(); its
        # length is unknown, so `indices` grows as frames arrive and `total` is max_frames or None.
        self.streaming = bool(getattr(source, "live", False))
        if self.streaming and (stride != 1 or resume):
            raise InputError("--stride and --resume do not apply to a live stream (rerun its capture folder instead)")
        if self.streaming:
            self.indices, self.total = [], max_frames or None
        else:
            self.indices = list(range(0, len(source), stride))[: max_frames if max_frames else None]
            if not self.indices:
                raise InputError(f"{getattr(source, 'path', 'input')}: no frames to process")
            self.total = len(self.indices)
        # The preset's resolution on this capture's shape (aspect kept; resolution.py).
        self.intrinsics = source.intrinsics.scaled(*source_working_size(source, config))
        self.slam = SplaTAM(config, self.intrinsics, device=self.device)
        self.slam.total_frames = self.total
        self.live_engine: LiveEngine | None = None     # the mapper thread of the live engine, once started
        self.records: list[dict] = []          # per-frame numbers kept for metrics.json and resume
        self.cursor = 0                        # next position in `indices` (frames read, skipped ones included)
        self.skipped: list[dict] = []          # bad frames: source_index and the one-line reason
        self.warn = lambda message: print(f"warning: {message}", file=sys.stderr, flush=True)
        self.references: list[np.ndarray | None] = []
        self.started = time.perf_counter()
        self._last_step = None
        if resume and self.out_dir is not None and not checkpoint.exists(self.out_dir / "checkpoint"):
            self.warn(f"{self.out_dir / 'checkpoint'}: no checkpoint written yet; starting from the first frame")
            resume = False
        if resume:
            self._resume()
        elif self.out_dir is not None:
            self.slam.keyframes.attach(self.out_dir / "checkpoint" / KEYFRAME_FILE)

    def _live_engine(self) -> LiveEngine:
        if self.live_engine is None:
            self.live_engine = LiveEngine(self.slam, self.config.live)
        return self.live_engine

    def keyframes(self) -> list[Keyframe]:
        return list(self.slam.keyframes)

    def map_version(self) -> MapVersion:
        """The newest map that may be read from any thread (live: the mapper's latest version;
        sequential: a copy of the map after the last frame, made once by the stepping thread)."""
        version = self.slam.latest_version()
        if self.live_engine is None and (version is None or version.frame_index != len(self.slam.w2cs) - 1):
            version = self.slam.publish(len(self.slam.w2cs) - 1)
        return version

    # ------------------------------------------------------------------ frames
    def frame(self, k: int) -> Frame:
        """Processed frame k at the working resolution, depth cut at max_depth."""
        return self.frame_at(int(self.records[k]["source_index"]))

    def frame_at(self, i: int, raw: Frame | None = None) -> Frame:
        """Capture frame i (or `raw`, that frame as received) at the working resolution, depth cut at
        max_depth; InputError naming the file when it is unusable."""
        return prepare_frame(self.source, i, self.intrinsics, self.config.max_depth, raw)

    def _next_frame(self) -> Frame | None:
        """The next usable frame; bad ones are skipped with a one-line warning (None at the end).

        Before the first usable frame the warnings wait: a capture refused as a whole gets its one
        error line and no list of warnings."""
        held = []
        while self.total is None or self.cursor < self.total:
            pulled = None
            if self.streaming:
                if (pulled := self.source.next_frame()) is None:   # the stream ended
                    break
                self.indices.append(pulled.index)
            i = int(self.indices[self.cursor])
            self.cursor += 1
            try:
                frame = self.frame_at(i, pulled)
                if self.config.tracking.use_reference_poses and not (
                        is_finite_pose(frame.c2w_ref) and (not self.references or is_finite_pose(self.references[0]))):
                    raise InputError(f"{getattr(self.source, 'path', 'input')} frame {i}: no finite reference pose "
                                     "(tracking.use_reference_poses)")
                for message in held:
                    self.warn(message)
                return frame
            except InputError as e:
                self.skipped.append(dict(source_index=i, reason=str(e)))
                if self.records:
                    self.warn(f"skipped {e}")
                else:
                    held.append(f"skipped {e}")
                if not self.records and len(self.skipped) >= MAX_LEADING_BAD_FRAMES:
                    raise InputError(f"{getattr(self.source, 'path', 'input')}: the first {len(self.skipped)} "
                                     f"frames are unusable (last: {e})") from None
        if not self.records and self.skipped:
            raise InputError(f"{getattr(self.source, 'path', 'input')}: no usable frame "
                             f"({len(self.skipped)} skipped; last: {self.skipped[-1]['reason']})")
        return None

    def step(self) -> FrameResult | None:
        k = len(self.records)
        frame = self._next_frame()
        if frame is None:
            return None
        given = None
        if self.config.tracking.use_reference_poses:
            given = invert_pose(self._reference_world(frame.c2w_ref, frame.c2w_ref if k == 0 else self.references[0]))
        if self.engine == "live":
            result = self._live_engine().process(frame, given)
        else:
            result = self.slam.process(frame, given)
        result.frame = frame
        now = time.perf_counter()   # wall time since the last frame (the first: its own processing)
        wall = now - self._last_step if self._last_step is not None else \
            result.tracking_seconds + result.mapping_seconds
        self._last_step = now
        self.references.append(frame.c2w_ref)
        self.records.append(dict(
            index=k, source_index=frame.index, timestamp=frame.timestamp, wall_seconds=wall,
            tracking_seconds=result.tracking_seconds, mapping_seconds=result.mapping_seconds,
            tracking_loss=result.tracking_loss, tracking_iterations=result.tracking_iterations,
            num_gaussians=result.num_gaussians, num_added=result.num_added, num_pruned=result.num_pruned,
            is_keyframe=result.is_keyframe, lost=result.lost))
        self._report_lost(result)
        if (k + 1) % RELEASE_MEMORY_EVERY == 0:
            release_free_memory()
        every = self.config.checkpoint_every
        if self.out_dir is not None and every and (k + 1) % every == 0 and (self.total is None or k + 1 < self.total):
            self.save_checkpoint()
        return result

    @property
    def lost(self) -> list[dict]:
        return [dict(index=r["index"], source_index=r["source_index"], reason=r["lost"])
                for r in self.records if r.get("lost")]

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
        return [invert_pose(w) for w in self.slam.w2cs]

    def has_reference(self) -> bool:
        return any(is_finite_pose(r) for r in self.references)

    def reference_c2w(self) -> list[np.ndarray | None] | None:
        """Reference poses in the SLAM world (first frame's camera), or None without any."""
        if not self.has_reference():
            return None
        return [self._reference_world(r, self.references[0]) for r in self.references]

    def ate_cm(self) -> float | None:
        refs = self.reference_c2w()
        if refs is None:
            return None
        pairs = [(e, r) for e, r in zip(self.estimated_c2w(), refs) if r is not None]
        if len(pairs) < 2:
            return None
        est, ref = zip(*pairs)
        return 100.0 * float(M.ate_rmse(np.array(est), np.array(ref)))

    # ------------------------------------------------------------------ checkpoints
    def _meta(self) -> dict:
        return dict(frames_done=len(self.records), total=self.total, indices=self.indices, engine=self.engine,
                    cursor=self.cursor, skipped=self.skipped, lost_tracking=self.slam.lost_tracking.state(),
                    records=self.records, references=[None if r is None else np.asarray(r).tolist()
                                                      for r in self.references],
                    config=self.config.to_dict(), intrinsics=self.intrinsics.to_dict(),
                    input=input_record(self.source), elapsed_seconds=time.perf_counter() - self.started)

    def save_checkpoint(self) -> None:
        if self.live_engine is not None:
            self.live_engine.drain()           # a consistent state: every tracked frame is in the map
        checkpoint.save(self.out_dir / "checkpoint", self.slam.state_arrays(), self._meta())

    def _resume(self) -> None:
        if self.out_dir is None:
            raise InputError("--out: nothing to resume (no checkpoint written yet)")
        ckpt = checkpoint.load(self.out_dir / "checkpoint")
        if ckpt.meta.get("indices") != self.indices:
            raise InputError(f"{self.out_dir}: the checkpoint was made with other frames "
                             "(--input/--stride/--max-frames must match the original run)")
        if ckpt.meta.get("config") != self.config.to_dict():
            raise InputError(f"{self.out_dir}: the checkpoint was made with another config")
        if ckpt.meta.get("engine", "sequential") != self.engine:
            raise InputError(f"{self.out_dir}: the checkpoint was made with --engine {ckpt.meta.get('engine')}")
        self.slam.load_state_arrays(ckpt.arrays, self.out_dir / "checkpoint" / KEYFRAME_FILE)
        self.records = list(ckpt.meta["records"])
        self.cursor = int(ckpt.meta.get("cursor", len(self.records)))
        self.skipped = list(ckpt.meta.get("skipped", []))
        if "lost_tracking" in ckpt.meta:
            self.slam.lost_tracking.load_state(ckpt.meta["lost_tracking"])
        self.references = [None if r is None else np.array(r) for r in ckpt.meta["references"]]
        self.started -= float(ckpt.meta.get("elapsed_seconds", 0.0))

    # ------------------------------------------------------------------ results
    def evaluate(self) -> dict:
        """Render metrics at the estimated poses on frame 0 and every eval_every-th frame."""
        every = max(1, self.config.eval_every)
        picks = [k for k in range(len(self.records))
                 if (k == 0 or (k + 1) % every == 0) and not self.records[k].get("lost")]   # a lost pose is a guess
        psnrs, ssims, depth_l1s = [], [], []
        g = self.slam.map.tensors(detach=True)
        for k in picks:
            frame = self.frame(k)
            with torch.no_grad():
                out = self.slam.renderer.render_visible(g, self.intrinsics, self.slam.w2cs[k])
            color = torch.as_tensor(frame.color, device=out.color.device)
            depth = torch.as_tensor(frame.depth, device=out.depth.device)
            psnrs.append(float(M.psnr(out.color, color)))
            ssims.append(float(M.ssim_metric(out.color, color)))
            depth_l1s.append(float(M.depth_l1(out.depth, depth)))
        mean = lambda xs: float(np.mean(xs)) if xs else None  # noqa: E731
        return dict(eval_frames=picks, psnr=mean(psnrs), ssim=mean(ssims),
                    depth_l1_cm=None if not depth_l1s else 100.0 * mean(depth_l1s))

    def metrics(self) -> dict:
        track = [r["tracking_seconds"] for r in self.records]
        mapping = [r["mapping_seconds"] for r in self.records]
        wall = [r["wall_seconds"] for r in self.records]
        out = dict(
            engine=self.engine, frames=len(self.records), frames_skipped=len(self.skipped),
            skipped=self.skipped, frames_lost=len(self.lost), lost=self.lost,
            frames_without_reference=sum(not is_finite_pose(r) for r in self.references) if self.has_reference() else 0,
            num_gaussians=len(self.slam.map), keyframes=len(self.slam.keyframes),
            ate_rmse_cm=self.ate_cm(),
            tracking_seconds_per_frame=float(np.mean(track)) if track else None,
            mapping_seconds_per_frame=float(np.mean(mapping)) if mapping else None,
            seconds_per_frame=float(np.mean(np.add(track, mapping))) if track else None,
            wall_seconds_per_frame=float(np.mean(wall)) if wall else None,
            wall_seconds_per_frame_median=float(np.median(wall[1:])) if len(wall) > 1 else None,
            peak_memory_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            device=str(self.device), machine=platform.processor() or platform.machine(),
            resolution=[self.intrinsics.width, self.intrinsics.height], config=self.config.name,
            intrinsics=self.intrinsics.to_dict(), input=input_record(self.source),
        )
        refs = self.reference_c2w()
        if refs is not None:
            pairs = [(w, invert_pose(r)) for w, r in zip(self.slam.w2cs, refs) if r is not None]
            if len(pairs) >= 2:
                est, ref = zip(*pairs)
                out["ate_mean_legacy_cm"] = 100.0 * float(M.ate_mean_legacy(np.array(est), np.array(ref)))
        if self.streaming:
            out.update(self.source.stats())   # received, dropped (never given to SLAM), rejected
        if self.device.type == "cuda":
            out["peak_gpu_memory_mb"] = torch.cuda.max_memory_allocated() / 2**20
        if self.live_engine is not None:
            live = self.live_engine
            out["live"] = dict(max_lag=self.config.live.max_lag, mapper_steps=live.mapper_steps,
                               mapper_seconds=live.mapper_seconds, tracker_wait_seconds=live.wait_seconds,
                               gaussians_added=live.num_added, gaussians_pruned=live.num_pruned)
        if self.slam.loop_closure is not None:
            out["loops_closed"] = len(self.slam.loop_closure.loops)
            out["loops_rejected"] = self.slam.loop_closure.rejected
            out["loops_rejected_by"] = dict(self.slam.loop_closure.rejected_by)
            out["loops"] = list(self.slam.loop_closure.loops)
        out.update(self.evaluate())
        out["per_frame"] = self.records
        return out

    def finish(self) -> dict:
        """Compute metrics and write the run folder (each file atomically)."""
        from .io.ply import write_ply
        from .io.trajectory import write_tum_trajectory

        if self.live_engine is not None:
            self.live_engine.drain()
            self.live_engine.close()
        # Time to the end of mapping counts: the live engine's last frames are mapped only now.
        if self.records and self._last_step is not None:
            self.records[-1]["wall_seconds"] += time.perf_counter() - self._last_step
            self._last_step = None
        result = self.metrics()
        if self.out_dir is not None:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            stamps = [r["timestamp"] for r in self.records]
            comments = {r["index"]: f"tracking lost at frame {r['index']} (capture frame {r['source_index']}): "
                        f"{r['reason']}; the pose below is not tracked (interpolated between the tracked frames on "
                        "either side, or held at the last tracked pose when the run ended lost)" for r in self.lost}
            write_tum_trajectory(self.out_dir / "trajectory.txt", stamps, self.estimated_c2w(), comments=comments)
            write_ply(self.out_dir / "map.ply", self.slam.map.to_numpy())
            write_text_atomic(self.out_dir / "config.yaml", yaml.safe_dump(self.config.to_dict(), sort_keys=False))
            write_text_atomic(self.out_dir / "metrics.json", json.dumps(result, indent=1))
            self.save_checkpoint()
        return result

