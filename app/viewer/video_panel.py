"""Camera-path videos from the viewer: camera keyframes taken from the browser's view, a preview
of the smooth path (drawn in the scene; the browser camera can fly along it), and an MP4
rendered with our renderer and offered for download.

The render runs on its own thread from one MapSnapshot (immutable numpy copies), never from the
live optimiser's tensors, so SLAM goes on beside it (sharing the CPU). One render at a time;
Cancel stops it and leaves no file.
"""

from __future__ import annotations

import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import viser

from splat_core.camera import Intrinsics, invert_pose
from splat_core.camera_path import CameraPath
from splat_core.errors import InputError

from .download import produce_and_send
from .novel_view import browser_camera
from .page_camera import place_c2w
from .cameras import wxyz_position


SIZES = ("640x480", "320x240", "1280x720", "1920x1080")
PATH_COLOR = (230, 60, 160)


class CameraPathPanel:
    """GUI folder "Camera path video" and the path under /camera_path in the scene."""

    def __init__(self, server: viser.ViserServer, snapshot_fn, *, export_dir: Path | None = None,
                 render_backend: str = "auto", order: float = 6.0, gui=None):
        self.server = server
        self.snapshot_fn = snapshot_fn      # () -> MapSnapshot | None
        self.export_dir = Path(export_dir) if export_dir else None
        self.render_backend = render_backend
        self.c2ws: list[np.ndarray] = []    # camera keyframes (camera-to-world)
        self.fovs: list[float] = []         # their vertical fields of view (radians)
        self.last_video: Path | None = None
        self.frames_done = 0
        self._lock = threading.Lock()       # guards the keyframe lists
        self._busy = threading.Lock()       # one render at a time
        self._cancel = threading.Event()
        gui = gui if gui is not None else server.gui   # the viewer passes its ControlGui (controlling pages)
        with gui.add_folder("Camera path video", order=order, expand_by_default=False):
            self.info = gui.add_markdown("Move the view, then **Add current view** (two or more).")
            self.add_button = gui.add_button("Add current view", icon=viser.Icon.CAMERA_PLUS)
            self.undo_button = gui.add_button("Remove last", icon=viser.Icon.ARROW_BACK_UP)
            self.clear_button = gui.add_button("Clear path", icon=viser.Icon.TRASH)
            self.seconds = gui.add_number("Seconds", initial_value=6.0, min=0.5, max=600.0, step=0.5)
            self.fps = gui.add_number("Frames per second", initial_value=30, min=1, max=60, step=1)
            self.size = gui.add_dropdown("Size", SIZES, initial_value=SIZES[0])
            self.preview_button = gui.add_button("Preview (fly the camera)", icon=viser.Icon.PLAYER_PLAY)
            self.render_button = gui.add_button("Render MP4", icon=viser.Icon.MOVIE)
            self.cancel_button = gui.add_button("Cancel render", icon=viser.Icon.X, disabled=True)
            self.progress = gui.add_progress_bar(0.0, animated=False)
        self.add_button.on_click(self._on_add)
        self.undo_button.on_click(lambda _: self.remove_last())
        self.clear_button.on_click(lambda _: self.clear())
        self.preview_button.on_click(self._on_preview)
        self.render_button.on_click(self._on_render)
        self.cancel_button.on_click(lambda _: self.cancel())
        for handle in (self.seconds, self.fps, self.size):
            handle.on_update(lambda _: self._edit(lambda: None))

    # ------------------------------------------------------------------ the path
    def _on_add(self, event) -> None:
        if event.client is None:
            return
        cam = event.client.camera
        _, w2c = browser_camera(event.client, 1)
        self.add_view(invert_pose(w2c), float(cam.fov))

    def add_view(self, c2w: np.ndarray, fov_y: float) -> None:
        """Append a camera keyframe (c2w, vertical fov in radians) and redraw the path."""
        self._edit(lambda: (self.c2ws.append(np.asarray(c2w, np.float64)), self.fovs.append(float(fov_y))))

    def remove_last(self) -> None:
        self._edit(lambda: self.c2ws and (self.c2ws.pop(), self.fovs.pop()))

    def clear(self) -> None:
        self._edit(lambda: (self.c2ws.clear(), self.fovs.clear()))

    def _edit(self, change) -> None:
        with self._lock:   # GUI callbacks run concurrently on viser's thread pool
            change()
            self._draw()

    def path(self) -> CameraPath | None:
        c2ws = list(self.c2ws)
        return CameraPath(np.stack(c2ws)) if c2ws else None

    def frames(self, n: int) -> np.ndarray:
        """n poses (c2w) along the path."""
        path = self.path()
        if path is None:
            raise InputError("the camera path has no keyframes; add views first")
        return path.sample(n)

    @property
    def fov(self) -> float:
        """The video's vertical field of view: the mean of the keyframes' (the browser's, usually one)."""
        return float(np.mean(self.fovs))

    def frame_count(self) -> int:
        return max(1, int(round(float(self.seconds.value) * float(self.fps.value))))

    def _draw(self) -> None:
        scene = self.server.scene
        scene.remove_by_name("/camera_path")
        n = len(self.c2ws)
        self.info.content = (f"{n} camera keyframe(s); " + ("add another one." if n < 2 else
                             f"{self.frame_count()} frames at {self.size.value}."))
        if n == 0:
            return
        width, height = (int(v) for v in self.size.value.split("x"))
        aspect = width / height
        for i, (c2w, fov) in enumerate(zip(self.c2ws, self.fovs)):
            wxyz, pos = wxyz_position(c2w)
            scene.add_camera_frustum(f"/camera_path/view_{i:03d}", fov=fov, aspect=aspect, scale=0.08,
                                     color=PATH_COLOR, wxyz=wxyz, position=pos)
        if n >= 2:
            centres = self.path().sample(max(20, 20 * n))[:, :3, 3]
            segments = np.stack([centres[:-1], centres[1:]], axis=1).astype(np.float32)
            scene.add_line_segments("/camera_path/line", segments, PATH_COLOR, thickness=3.0,
                                    thickness_units="screen")

    # ------------------------------------------------------------------ preview
    def _on_preview(self, event) -> None:
        if event.client is not None and self.c2ws:
            threading.Thread(target=self.fly, args=(event.client,), name="camera-path-preview", daemon=True).start()

    def fly(self, client, rate_hz: float = 25.0) -> None:
        """Move the client's browser camera along the path in real time (Seconds long)."""
        n = max(2, int(float(self.seconds.value) * rate_hz))
        fov = self.fov
        for c2w in self.frames(n):
            with client.atomic():
                place_c2w(client, c2w)
                client.camera.fov = fov
            time.sleep(1.0 / rate_hz)

    # ------------------------------------------------------------------ render
    def _on_render(self, event) -> None:
        threading.Thread(target=self._render_and_send, args=(event.client,), name="camera-path-video",
                         daemon=True).start()

    def _render_and_send(self, client) -> None:
        produce_and_send(client, self.info, self.render_video, "video",
                         lambda path: ("Video ready", f"{path.name} ({path.stat().st_size:,} bytes), written to {path}"))

    def render_video(self, out: Path | None = None) -> Path | None:
        """Render the path into an MP4 (the export folder's camera_path.mp4 by default) from the
        latest snapshot; returns the path, or None when another render is running or it was cancelled."""
        from ..video import Cancelled, parse_size, render_frames, write_mp4

        if len(self.c2ws) < 2:
            raise InputError("the camera path needs at least two keyframes")
        snap = self.snapshot_fn()
        if snap is None or snap.num_gaussians == 0:
            raise InputError("there is no map to render yet")
        if not self._busy.acquire(blocking=False):
            return None
        try:
            self._cancel.clear()
            self.render_button.disabled, self.cancel_button.disabled = True, False
            width, height = parse_size(self.size.value)
            n = self.frame_count()
            c2ws = self.frames(n)
            intr = Intrinsics.from_fov(self.fov, width, height)
            out = Path(out) if out else (self.export_dir or Path(tempfile.mkdtemp(prefix="splatam-video-"))) / "camera_path.mp4"
            self.frames_done = 0
            self.progress.value = 0.0
            frames = render_frames(snap.gaussians, intr, c2ws, near=snap.near_plane, backend=self.render_backend,
                                   cancelled=self._cancel.is_set)
            start = time.perf_counter()
            try:
                write_mp4(out, frames, fps=float(self.fps.value), size=(width, height), total=n,
                          on_frame=self._on_frame(n))
            except Cancelled:
                self.info.content = "Render cancelled."
                return None
            rate = n / max(time.perf_counter() - start, 1e-9)
            self.info.content = f"Wrote {n} frames ({width}x{height}, {rate:.1f} frames/s) to `{out}`."
            self.last_video = out
            return out
        finally:
            self.render_button.disabled, self.cancel_button.disabled = False, True
            self._busy.release()

    def cancel(self) -> None:
        """Stop a running render (it leaves no file)."""
        self._cancel.set()

    def _on_frame(self, n: int):
        def update(i: int) -> None:
            self.frames_done = i
            self.progress.value = 100.0 * i / n
        return update
