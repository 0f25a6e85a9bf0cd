"""The web viewer: builds the viser scene and GUI from MapSnapshots. No SLAM logic here.

    app = build_viewer(server, source, export_dir=..., render_backend="auto")
    ...
    app.close()

`source` is anything with `latest() -> MapSnapshot | None`: the SlamWorker (which also has
pause / resume / step_once) or a StaticSource for browsing a finished run. One viewer-update
thread pulls the latest snapshot at <= 2 Hz and pushes changes to viser (map chunks, frustums,
trajectories, status, plots, live images). One render thread (RenderService) serves the
novel-view mode of every client and the keyframe comparison, each slot latest-request-only.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import numpy as np
import torch
import viser

from splat_core.camera import Intrinsics, invert_pose

from .assets import WebAssets, apply_theme, load_assets
from splat_core.metrics import psnr

from ..video import gaussians_of
from ..images import colorize_depth, depth_max_of, mosaic, to_uint8
from .novel_view import MODES, NovelView, RenderService
from ..snapshot import MapSnapshot
from .export_panel import ExportPanel
from .mesh_layer import MeshLayer
from .measure import MeasureTool
from .panels import Panels
from .refine_panel import RefinePanel
from .scene import CameraLayer, MapLayer, wxyz_position
from .video_panel import CameraPathPanel

log = logging.getLogger(__name__)


class StaticSource:
    """A fixed snapshot (browse mode: a finished run or a .ply, no SLAM)."""

    def __init__(self, snapshot: MapSnapshot):
        self._snapshot = snapshot

    def latest(self) -> MapSnapshot:
        return self._snapshot


class ViewerApp:
    def __init__(self, server: viser.ViserServer, source, *, export_dir: Path | None = None,
                 render_backend: str = "auto", update_hz: float = 2.0, assets: WebAssets | None = None,
                 novel_full_width: int = 480, novel_low_width: int = 128, scrub_width: int = 320,
                 consolidate_every: int = 5, consolidate_interval_s: float = 10.0,
                 map_updates: str = "keyframes", browser_splats: int | None = None,
                 draw_while_running: str = "splats"):
        self.server = server
        self.source = source
        self.export_dir = Path(export_dir) if export_dir else None
        self.render_backend = render_backend
        self.update_period = 1.0 / update_hz
        self.scrub_width = scrub_width
        self.novel_full_width, self.novel_low_width = novel_full_width, novel_low_width
        self.assets = assets or load_assets()
        self.has_controls = hasattr(source, "pause")

        apply_theme(server, self.assets)
        server.scene.set_up_direction("-y")   # SLAM world = first camera, OpenCV: up is -y
        server.initial_camera.position = (0.0, -0.6, -1.6)
        server.initial_camera.look_at = (0.0, 0.0, 1.5)
        server.initial_camera.up = (0.0, -1.0, 0.0)

        self.mesh_layer = MeshLayer(server, lambda: self.source.latest())   # owns /map: before any chunk
        self.map_layer = MapLayer(server, consolidate_every, consolidate_interval_s, map_updates, browser_splats,
                                  draw_while_running)
        self.camera_layer = CameraLayer(server, self.assets.colors, self._on_keyframe_click)
        self.panels = Panels(server, self.assets.help_markdown, self.has_controls, map_updates, browser_splats,
                             draw_while_running)
        self.refine_panel = RefinePanel(server, source, self.wake)
        self.source = self.refine_panel.source   # the same snapshots, with the refined map once refined
        self.export_panel = ExportPanel(server, self.source, export_dir=self.export_dir, folder=self.panels.export_folder,
                                        mesh=self.mesh_layer)
        self.video_panel = CameraPathPanel(server, self.source.latest, export_dir=self.export_dir,
                                           render_backend=render_backend)
        self.measure = MeasureTool(server, self.source.latest, render_backend)
        self.renderer = RenderService()
        self.renderer.start()

        self.novel_views: dict[int, NovelView] = {}
        self._scrub: int | None = None            # keyframe position shown, None = latest
        self._snapshot: MapSnapshot | None = None
        self.applied: MapSnapshot | None = None
        self._keyframe_view_of: tuple | None = None   # (position, frame) last sent to the panel
        self._render_cache: tuple | None = None   # (map, birth limit, Gaussians born up to it)
        self._programmatic = 0
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._reapply = threading.Event()
        self._last_state = None
        self._camera_placed = False
        self.updates = 0
        self.first_map_at: float | None = None

        self._wire_callbacks()
        server.on_client_connect(self._on_client_connect)
        server.on_client_disconnect(self._on_client_disconnect)
        self._thread = threading.Thread(target=self._update_loop, name="viewer-update", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ wiring
    def _wire_callbacks(self) -> None:
        p = self.panels
        if self.has_controls:
            p.pause_button.on_click(lambda _: self._control("pause"))
            p.resume_button.on_click(lambda _: self._control("resume"))
            p.step_button.on_click(lambda _: self._control("step_once"))
        p.map_updates.on_update(self._on_map_updates)
        p.browser_splats.on_update(self._on_browser_splats)
        p.draw_while_running.on_update(self._on_draw_while_running)
        p.keyframe_slider.on_update(self._on_slider)
        p.follow_latest.on_update(self._on_follow)
        p.export_ply_button.on_click(lambda ev: self._export(ev, "ply"))
        p.export_traj_button.on_click(lambda ev: self._export(ev, "trajectory"))

    def _control(self, action: str) -> None:
        getattr(self.source, action)()
        p = self.panels
        with self.server.atomic():   # immediate feedback; the next snapshot confirms it
            p.pause_button.disabled = action == "pause" or action == "step_once"
            p.resume_button.disabled = action == "resume"
            p.step_button.disabled = action == "resume"
        self.wake()

    def _on_map_updates(self, _event) -> None:
        self.map_layer.set_policy(self.panels.map_updates.value)
        self._reapply.set()   # the latest snapshot again, under the new policy
        self.wake()

    def _on_browser_splats(self, _event) -> None:
        self.map_layer.budget = int(self.panels.browser_splats.value) or None
        self._reapply.set()
        self.wake()

    def _on_draw_while_running(self, _event) -> None:
        self.map_layer.running_style = self.panels.draw_while_running.value
        self._reapply.set()
        self.wake()

    def _on_client_connect(self, client: viser.ClientHandle) -> None:
        with client.gui.add_folder("Novel view", order=5):
            dropdown = client.gui.add_dropdown("View", tuple(MODES), initial_value=next(iter(MODES)))
        view = NovelView(client, self.renderer, self._render_map, full_width=self.novel_full_width,
                         low_width=self.novel_low_width)
        view.mode_dropdown = dropdown
        dropdown.on_update(lambda _: view.set_mode(MODES[dropdown.value]))
        with self._lock:
            self.novel_views[client.client_id] = view

    def _on_client_disconnect(self, client: viser.ClientHandle) -> None:
        with self._lock:
            view = self.novel_views.pop(client.client_id, None)
        if view is not None:
            view.close()

    # ------------------------------------------------------------------ update loop
    def wake(self) -> None:
        """Apply the next snapshot soon (after a button press) instead of at the next tick."""
        self._wake.set()

    def _update_loop(self) -> None:
        while not self._stop.is_set():
            try:
                self.update_once()
            except Exception:
                log.exception("viewer update failed")
            self._wake.wait(self.update_period)
            self._wake.clear()

    def update_once(self) -> bool:
        """Apply the latest snapshot if it is new; returns True when something changed."""
        snap = self.source.latest()
        reapply = self._reapply.is_set()
        self._reapply.clear()
        if snap is None or (self._snapshot is not None and snap.version == self._snapshot.version
                            and not reapply):
            return False
        with self._lock:
            prev, self._snapshot = self._snapshot, snap
        state_changed = prev is None or prev.state != snap.state
        # Consolidate (refresh every chunk) when the run pauses, ends, or in browse mode.
        force = state_changed and snap.state in ("paused", "finished", "stopped", "browse")
        # The 3D scene (map, cameras, trajectories) follows the map update policy, and shows at once
        # when tracking is lost or found: any scene message makes viser's page redraw (docs/viewer-notes.md §3).
        if force or self.map_layer.follows(snap) or snap.tracking_lost != self.camera_layer.lost_shown:
            if self.map_layer.update(snap, force_consolidate=force) and self.first_map_at is None \
                    and snap.num_gaussians:
                self.first_map_at = time.monotonic()
            self.camera_layer.update(snap)
        if prev is None or prev.map_version != snap.map_version or force:   # our renders follow
            for view in list(self.novel_views.values()):                    # every map version
                view.refresh()
        if not self._camera_placed and snap.num_gaussians:
            self._place_initial_camera(snap)
        p = self.panels
        p.update_status(snap)
        p.update_plots(snap)
        if snap.live is not None and (prev is None or prev.live is not snap.live):
            p.update_live(snap)
        self._update_keyframe_slider(snap)
        self.mesh_layer.sync(snap)
        self.updates += 1
        self.applied = snap      # fully pushed to viser (tests and the benchmark wait on this)
        return True

    def _place_initial_camera(self, snap: MapSnapshot) -> None:
        """New clients start behind the first camera, looking at the middle of the map."""
        self._camera_placed = True
        centre = np.median(snap.gaussians["means"], axis=0).astype(np.float64)
        dist = max(float(np.linalg.norm(centre)), 0.3)
        c2w0 = snap.estimated_c2w[0] if len(snap.estimated_c2w) else np.eye(4)
        back = c2w0[:3, :3] @ np.array([0.0, -0.3, -0.8]) * dist
        self.server.initial_camera.look_at = tuple(centre)
        self.server.initial_camera.position = tuple(c2w0[:3, 3] + back)

    # ------------------------------------------------------------------ keyframe scrubbing
    def _update_keyframe_slider(self, snap: MapSnapshot) -> None:
        K = len(snap.keyframes)
        p = self.panels
        if K == 0:
            return
        slider = p.keyframe_slider
        self._programmatic += 1
        try:
            if slider.max != max(K - 1, 1):
                slider.max = max(K - 1, 1)
            slider.disabled = K < 2
            if p.follow_latest.value and slider.value != K - 1:
                slider.value = K - 1
        finally:
            self._programmatic -= 1
        if p.follow_latest.value and self._keyframe_view_of != (K - 1, snap.keyframes[-1].frame_index):
            self._request_keyframe_view(K - 1, snap)

    def _on_follow(self, _event) -> None:
        if self._programmatic:
            return
        if self.panels.follow_latest.value:
            self.scrub_to(None)

    def _on_slider(self, event) -> None:
        if self._programmatic:
            return
        snap = self._snapshot
        if snap is None or not snap.keyframes:
            return
        k = int(self.panels.keyframe_slider.value)
        K = len(snap.keyframes)
        if k >= K - 1 and self.panels.follow_latest.value:
            self.scrub_to(None)
            return
        self.scrub_to(min(k, K - 1), client=getattr(event, "client", None))

    def scrub_to(self, k: int | None, client=None) -> None:
        """Show the map as it was at keyframe position k (None: follow the latest map)."""
        snap = self._snapshot
        with self._lock:
            self._scrub = k
        if k is not None and self.panels.follow_latest.value:
            self._programmatic += 1
            try:
                self.panels.follow_latest.value = False
            finally:
                self._programmatic -= 1
        self.map_layer.show_upto(k)
        if snap is None or not snap.keyframes:
            return
        pos = len(snap.keyframes) - 1 if k is None else k
        kf = snap.keyframes[pos]
        self.camera_layer.select(None if k is None else kf.frame_index, hide=k is not None)
        if k is not None:
            clients = [client] if client is not None else list(self.server.get_clients().values())
            for c in clients:
                self._fly_to(c, kf.c2w)
        for view in list(self.novel_views.values()):
            view.refresh()
        self._request_keyframe_view(pos, snap)

    def _request_keyframe_view(self, pos: int, snap: MapSnapshot) -> None:
        self._keyframe_view_of = (pos, snap.keyframes[pos].frame_index)
        self.renderer.submit("keyframe", lambda: self._render_keyframe(pos, snap))

    def _render_keyframe(self, pos: int, snap: MapSnapshot) -> None:
        kf = snap.keyframes[pos]
        title = f"Keyframe {pos + 1} / {len(snap.keyframes)} (frame #{kf.frame_index} )"
        if kf.color is None or snap.intrinsics is None:
            self.panels.keyframe_info.content = title
            self.panels.keyframe_image.image = kf.thumbnail
            return
        intr = snap.intrinsics
        if intr.width > self.scrub_width:
            intr = intr.scaled(self.scrub_width, max(1, round(intr.height * self.scrub_width / intr.width)))
        out = self._render_map(intr, invert_pose(kf.c2w), snap=snap, birth_limit=kf.frame_index)
        captured = np.asarray(kf.color, np.float32)
        if captured.shape[1] != intr.width:
            import cv2
            captured = cv2.resize(captured, (intr.width, intr.height), interpolation=cv2.INTER_AREA)
        tiles = [(to_uint8(captured), "captured")]
        text = title
        if out is not None:
            color = out.color.detach().cpu().numpy()
            value = psnr(color, captured)
            tiles.append((to_uint8(color), f"render {value:.1f} dB"))
            depth = out.depth.detach().cpu().numpy()
            tiles.append((colorize_depth(depth, depth_max_of(kf.depth, depth)), "render depth"))
            text += f"  \nPSNR of our render from this pose: **{value:.2f} dB**"
        self.panels.keyframe_image.image = mosaic([tiles], tile_width=200)
        self.panels.keyframe_info.content = text

    def _on_keyframe_click(self, event, frame_index: int) -> None:
        snap = self._snapshot
        if snap is None:
            return
        frames = [kf.frame_index for kf in snap.keyframes]
        if frame_index in frames and event.client is not None:
            self._fly_to(event.client, snap.keyframes[frames.index(frame_index)].c2w)

    @staticmethod
    def _fly_to(client, c2w: np.ndarray) -> None:
        wxyz, pos = wxyz_position(c2w)
        with client.atomic():
            client.camera.wxyz = wxyz
            client.camera.position = pos

    # ------------------------------------------------------------------ our renderer
    def _render_map(self, intr: Intrinsics, w2c: np.ndarray, snap: MapSnapshot | None = None,
                    birth_limit: int | None = None):
        """Render the snapshot's map (Gaussians born up to the scrubbed keyframe) or None."""
        from splat_core.render import Renderer

        snap = snap or self._snapshot
        if snap is None or snap.num_gaussians == 0:
            return None
        if birth_limit is None and self._scrub is not None and snap.keyframes:
            birth_limit = snap.keyframes[min(self._scrub, len(snap.keyframes) - 1)].frame_index
        gaussians = gaussians_of(snap.gaussians)
        if birth_limit is not None:     # the map as it was at a keyframe: one selection per map and keyframe
            key = (snap.map_version, id(snap.gaussians), birth_limit)
            if self._render_cache is None or self._render_cache[0] != key:
                keep = torch.as_tensor(np.asarray(snap.gaussians["birth_frame"]) <= birth_limit)
                self._render_cache = (key, gaussians.select(keep.to(gaussians.means.device)))
            gaussians = self._render_cache[1]
        with torch.no_grad():
            return Renderer(snap.near_plane, self.render_backend).render_visible(
                gaussians, intr, np.asarray(w2c, np.float32))

    # ------------------------------------------------------------------ export
    def export_files(self, what: str) -> tuple[str, bytes, Path | None]:
        """(file name, content, path written in the export folder or None)."""
        from splat_core.io.atomic import write_bytes_atomic
        from splat_core.io.ply import ply_bytes

        snap = self.source.latest()
        if what == "ply":
            name, content = "map.ply", ply_bytes(snap.gaussians)
        else:
            name, content = "trajectory.txt", trajectory_bytes(snap)
        path = None
        if self.export_dir is not None:
            path = write_bytes_atomic(self.export_dir / name, content)
        return name, content, path

    def _export(self, event, what: str) -> None:
        name, content, path = self.export_files(what)
        where = f"written to `{path}`" if path else "not written (no run folder)"
        self.panels.export_info.content = f"{name}: {len(content):,} bytes, {where}"
        if event.client is not None:
            event.client.send_file_download(name, content, save_immediately=True)
            event.client.add_notification(f"Exported {name}", f"{where}", auto_close_seconds=8.0)

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        self.video_panel.cancel()
        self._stop.set()
        self._wake.set()
        self.refine_panel.close()
        self.renderer.stop()
        self._thread.join(timeout=5)
        self.renderer.join(timeout=30)


def trajectory_bytes(snap: MapSnapshot) -> bytes:
    """The estimated trajectory as TUM text (c2w, the input's timestamps)."""
    import tempfile

    from splat_core.io.trajectory import write_tum_trajectory

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "trajectory.txt"
        write_tum_trajectory(path, snap.timestamps[: len(snap.estimated_c2w)], snap.estimated_c2w)
        return path.read_bytes()


def build_viewer(server: viser.ViserServer, source, **kwargs) -> ViewerApp:
    """Build the GUI and scene on `server` and start pulling snapshots from `source`."""
    return ViewerApp(server, source, **kwargs)
