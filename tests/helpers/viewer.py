"""Helpers for the viewer tests: a small fake run (pipeline.SlamRun, what the worker may use), and test maps."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from splat_core.camera import Intrinsics, invert_pose
from splat_core.config import Config
from splat_core.frame import Frame
from splat_core.gaussians import GaussianMap
from splat_core.keyframes import Keyframe
from splat_core.slam import FrameResult, MapVersion

INTR = Intrinsics(60.0, 60.0, 39.5, 29.5, 80, 60)


class MessageLog:
    """A fake client's `_websock_connection`, as app/viewer/page_camera.py uses it: the messages queued
    for the page, and the camera pose they place it at."""

    def __init__(self):
        self.messages = []

    def queue_message(self, message):
        self.messages.append(message)

    def placed(self) -> dict:
        """{"position", "look_at", "up"} of the last camera messages (None where none was sent)."""
        last = {"SetCameraPositionMessage": ("position", "position"), "SetCameraLookAtMessage": ("look_at", "look_at"),
                "SetCameraUpDirectionMessage": ("up", "position")}
        out = dict.fromkeys(("position", "look_at", "up"))
        for m in self.messages:
            if type(m).__name__ in last:
                key, field = last[type(m).__name__]
                out[key] = np.asarray(getattr(m, field), np.float64)
        return out
FRAME_COLORS = [(1.0, 0.1, 0.1), (0.1, 0.3, 1.0), (0.1, 0.9, 0.2), (0.9, 0.9, 0.1), (0.8, 0.2, 0.9)]


def blob_map(n: int, frame_index: int = 0, color=(1.0, 0.1, 0.1), center=(0.0, 0.0, 2.0),
             spread: float = 0.4, radius: float = 0.03, seed: int = 0, opacity: float = 0.9) -> GaussianMap:
    """n Gaussians in a flat square patch facing the first camera."""
    rng = np.random.default_rng(seed)
    pts = np.asarray(center) + np.c_[rng.uniform(-spread, spread, (n, 2)), rng.normal(0, 0.01, n)]
    cols = np.tile(np.asarray(color, np.float32), (n, 1))
    return GaussianMap.from_points(pts, cols, np.full(n, radius), frame_index, opacity=opacity)


class FakePipeline:
    """A SlamRun on a scripted scene: frame k adds `per_frame` Gaussians in colour k
    (a patch shifted right per frame), keyframe every `keyframe_every` frames, camera sliding +x."""

    def __init__(self, total: int = 6, per_frame: int = 300, keyframe_every: int = 2,
                 frame_seconds: float = 0.0, out_dir: Path | None = None, with_reference: bool = True):
        self.total = total
        self.per_frame = per_frame
        self.keyframe_every = keyframe_every
        self.frame_seconds = frame_seconds
        self.out_dir = out_dir
        self.with_reference = with_reference
        self.config, self.intrinsics = Config(), INTR
        self.streaming = False                     # not a LiveSource (SlamRun.streaming)
        self.map = GaussianMap.empty()
        self.kf: list[Keyframe] = []
        self.records: list[dict] = []
        self.skipped: list[dict] = []
        self.lost: list[dict] = []
        self.versions = 0
        self.w2cs: list[np.ndarray] = []
        self.finished = False

    def _c2w(self, k: int) -> np.ndarray:
        c2w = np.eye(4)
        c2w[0, 3] = 0.1 * k
        return c2w

    def frame(self, k: int) -> Frame:
        color = np.zeros((INTR.height, INTR.width, 3), np.float32)
        color[:] = FRAME_COLORS[k % len(FRAME_COLORS)]
        depth = np.full((INTR.height, INTR.width), 2.0, np.float32)
        return Frame(k, k / 30.0, color, depth, INTR, self._c2w(k))

    def step(self):
        k = len(self.w2cs)
        if k >= self.total:
            return None
        if self.frame_seconds:
            time.sleep(self.frame_seconds)
        w2c = invert_pose(self._c2w(k))
        self.w2cs.append(w2c)
        new = blob_map(self.per_frame, k, FRAME_COLORS[k % len(FRAME_COLORS)],
                       center=(0.5 * k - 0.5, 0.0, 2.0), spread=0.2, seed=k)
        self.map.append(new)
        frame = self.frame(k)
        is_kf = k % self.keyframe_every == 0
        if is_kf:
            self.kf.append(Keyframe.from_images(k, w2c, frame.color, frame.depth))
        self.records.append(dict(index=k, wall_seconds=0.03))
        return FrameResult(k, k / 30.0, w2c, is_kf, len(self.map), self.per_frame, 0,
                           0.01, 0.02, 0.5 / (k + 1), source_index=k, frame=frame)

    def keyframes(self):
        return list(self.kf)

    def map_version(self):
        self.versions += 1
        g = self.map.tensors(detach=True)
        return MapVersion(self.versions, len(self.w2cs) - 1, type(g)(*(x.clone() for x in (
            g.means, g.colors, g.rotations, g.logit_opacities, g.log_scales))), self.map.birth_frame.clone())

    def estimated_c2w(self):
        return [invert_pose(w) for w in self.w2cs]

    def reference_c2w(self):
        if not self.with_reference:
            return None
        out = []
        for k in range(len(self.w2cs)):
            c2w = self._c2w(k)
            c2w[1, 3] = 0.02 * k
            out.append(c2w)
        return out

    def estimated_c2w_array(self):
        return np.array(self.estimated_c2w()).reshape(-1, 4, 4)

    def reference_c2w_array(self):
        ref = self.reference_c2w()
        return None if ref is None else np.array(ref).reshape(-1, 4, 4)

    def ate_cm(self):
        return 2.0 * len(self.w2cs) if self.with_reference and len(self.w2cs) > 1 else None

    def finish(self):
        self.finished = True
        if self.out_dir is not None:
            from splat_core.io.ply import write_ply
            from splat_core.io.trajectory import write_tum_trajectory
            write_ply(self.out_dir / "map.ply", self.map.to_numpy())
            write_tum_trajectory(self.out_dir / "trajectory.txt", [k / 30.0 for k in range(len(self.w2cs))],
                                 self.estimated_c2w())
        return {"frames": len(self.w2cs)}


def wait_until(predicate, timeout: float = 30.0, interval: float = 0.1, what: str = "condition"):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(interval)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


def apply_snapshot(app, source, snap) -> None:
    """Hand the viewer `snap` (through a source whose `.snap` it reads) and wait until it is applied."""
    source.snap = snap
    app.wake()
    wait_until(lambda: app.applied is not None and app.applied.frame_index == snap.frame_index, 60,
               what=f"snapshot {snap.version}")


def click(button) -> None:
    """Press a viser GUI button from a test: its on_click callbacks with an event from no client."""
    from viser import GuiEvent

    callbacks = button.callbacks if hasattr(button, "callbacks") else button._impl.update_cb   # a ControlGui widget
    for callback in list(callbacks):
        callback(GuiEvent(client=None, client_id=None, target=button))
