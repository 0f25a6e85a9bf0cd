"""The web viewer: builds the viser scene and GUI from MapSnapshots. No SLAM logic here.

    app = build_viewer(server, source, export_dir=..., render_backend="auto")
    ...
    app.close()

`source` is anything with `latest() -> MapSnapshot | None`: the SlamWorker (which also has
pause / resume / step_once) or a StaticSource for browsing a finished run. The viewer reads it
through a SnapshotFeed (feed.py), which puts a refined map in once there is one. One
viewer-update thread pulls the latest snapshot at <= 2 Hz (<= 1 Hz while SLAM runs) and pushes
changes to viser (map chunks, frustums, trajectories, status, plots, live images). One render
thread (RenderService) serves the novel-view mode of every client and the keyframe panels, each
slot latest-request-only.

Every page gets the shared panels and its own Keyframes panel and novel view (scrub.py); pages
whose visitor may control the run (access.py: all of them unless tokens say otherwise) also get
the run controls, export, refine and camera-path panels (a ControlGui, control_gui.py).
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import numpy as np
import torch
import viser

from splat_core.camera import Intrinsics

from ..video import gaussians_of
from ..snapshot import MapSnapshot
from .access import Access, tolerate_malformed_messages
from .assets import WebAssets, apply_theme, load_assets
from .control_gui import ControlGui
from .export_panel import ExportPanel
from .feed import SnapshotFeed, controls_of
from .framing import MapFraming
from .loops import LoopLayer
from .mesh_layer import MeshLayer
from .measure import MeasureTool
from .novel_view import MODES, NovelView, RenderService
from .panels import Panels
from .refine_panel import RefinePanel
from .cameras import CameraLayer
from .scene import MapLayer
from .scrub import KeyframeScrubber
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
                 render_backend: str = "auto", update_hz: float = 2.0, running_update_hz: float = 1.0,
                 assets: WebAssets | None = None,
                 novel_full_width: int = 480, novel_low_width: int = 128, scrub_width: int = 320,
                 consolidate_every: int = 5, consolidate_interval_s: float = 10.0,
                 map_updates: str = "keyframes", browser_splats: int | None = None,
                 draw_while_running: str = "auto", access: Access | None = None,
                 preview_frame=None):
        self.server = server
        tolerate_malformed_messages()            # a bad websocket message is dropped, the page stays
        self.feed = SnapshotFeed(source)
        self.source = self.feed                  # what every part of the viewer reads
        self.controls = controls_of(source)      # pause / resume / step_once, or None when browsing
        self.access = access or Access({})
        self.export_dir = Path(export_dir) if export_dir else None
        self.render_backend = render_backend
        self.update_period = 1.0 / update_hz
        # While SLAM runs, the page's panels follow once a second: each update is tens of viser
        # messages that the server sends and the page handles on the cores SLAM uses (at 2 Hz
        # SLAM's frames took ~7 ms longer with a software-WebGL page, 2.5 ms with no page; Viewer
        # in docs/benchmarks.md). A button press still shows at once (wake()).
        self.running_update_period = max(self.update_period, 1.0 / running_update_hz)
        self.novel_full_width, self.novel_low_width = novel_full_width, novel_low_width
        self.assets = assets or load_assets()
        self.has_controls = self.controls is not None

        apply_theme(server, self.assets)
        server.scene.set_up_direction("-y")   # SLAM world = first camera, OpenCV: up is -y
        server.initial_camera.position = (0.0, -0.6, -1.6)
        server.initial_camera.look_at = (0.0, 0.0, 1.5)
        server.initial_camera.up = (0.0, -1.0, 0.0)

        self.control_gui = ControlGui()
        self.renderer = RenderService()
        self.mesh_layer = MeshLayer(server, lambda: self.feed.latest(), gui=self.control_gui)   # owns /map: before any chunk
        self.map_layer = MapLayer(server, consolidate_every, consolidate_interval_s, map_updates, browser_splats,
                                  draw_while_running)
        self.scrubber = KeyframeScrubber(server, self.map_layer, None, self.renderer, self._render_map,
                                         width=scrub_width, on_change=self._on_page_view_changed)
        self.camera_layer = CameraLayer(server, self.assets.colors, self.scrubber.on_frustum_click)
        self.scrubber.camera_layer = self.camera_layer
        self.loop_layer = LoopLayer(server, self.assets.colors)
        self.framing = MapFraming(server)
        self.panels = Panels(server, self.assets.help_markdown, self.has_controls, map_updates, browser_splats,
                             draw_while_running, controls=self.control_gui)
        if preview_frame is not None:
            self.panels.show_preview(preview_frame.color, preview_frame.depth, preview_frame.index)
        self.export_panel = ExportPanel(server, self.feed, export_dir=self.export_dir, gui=self.control_gui,
                                        mesh=self.mesh_layer)
        self.refine_panel = RefinePanel(server, self.feed, gui=self.control_gui)
        self.feed.on_refined(self.wake)
        self.video_panel = CameraPathPanel(server, self.feed.latest, export_dir=self.export_dir,
                                           render_backend=render_backend, gui=self.control_gui)
        self.measure = MeasureTool(server, self.feed.latest, render_backend)
        self.renderer.start()

        self.novel_views: dict[int, NovelView] = {}
        self._snapshot: MapSnapshot | None = None
        self.applied: MapSnapshot | None = None
        self._render_cache: tuple | None = None   # (map, birth limit, Gaussians born up to it)
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._reapply = threading.Event()
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
        p.show_keyframes.on_update(lambda _: self.camera_layer.set_keyframes_visible(p.show_keyframes.value))

    def _control(self, action: str) -> None:
        getattr(self.controls, action)()
        p = self.panels   # immediate feedback; the next snapshot confirms it
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

    def role(self, client) -> str:
        return self.access.role(client)

    def _on_client_connect(self, client: viser.ClientHandle) -> None:
        self.framing.attach(client)
        if self.role(client) == "control":
            self.control_gui.attach(client)
        else:
            with client.gui.add_folder("View only", order=0.5):
                client.gui.add_markdown("This page is **view only**: the run's controls, export and refine "
                                        "are for the person running the viewer.")
        self.scrubber.attach(client)
        with client.gui.add_folder("Novel view", order=5):
            dropdown = client.gui.add_dropdown("View", tuple(MODES), initial_value=next(iter(MODES)),
                                               hint="WebGL splats, or our SLAM renderer from your camera "
                                                    "(this page only)")
        cid = client.client_id
        view = NovelView(client, self.renderer,
                         lambda intr, w2c: self._render_map(intr, w2c, birth_limit=self.scrubber.birth_limit(cid)),
                         full_width=self.novel_full_width, low_width=self.novel_low_width)
        view.mode_dropdown = dropdown
        dropdown.on_update(lambda _: view.set_mode(MODES[dropdown.value]))
        with self._lock:
            self.novel_views[cid] = view

    def _on_client_disconnect(self, client: viser.ClientHandle) -> None:
        self.control_gui.detach(client.client_id)
        self.framing.detach(client.client_id)
        self.scrubber.detach(client.client_id)
        with self._lock:
            view = self.novel_views.pop(client.client_id, None)
        if view is not None:
            view.close()

    def _on_page_view_changed(self, client_id: int) -> None:
        view = self.novel_views.get(client_id)
        if view is not None:
            view.refresh()

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
            self._wake.wait(self.next_wait())
            self._wake.clear()

    def next_wait(self) -> float:
        """Seconds to the next update unless woken: longer while the snapshot shown is of SLAM running."""
        running = self._snapshot is not None and self._snapshot.state == "running"
        return self.running_update_period if running else self.update_period

    def update_once(self) -> bool:
        """Apply the latest snapshot if it is new; returns True when something changed."""
        snap = self.feed.latest()
        reapply = self._reapply.is_set()
        self._reapply.clear()
        if snap is not None:
            self.refine_panel.sync(snap)     # every tick: the button follows the job's end too
        if snap is None or (self._snapshot is not None and snap.version == self._snapshot.version
                            and not reapply):
            return False
        with self._lock:
            prev, self._snapshot = self._snapshot, snap
        state_changed = prev is None or prev.state != snap.state
        # Consolidate (refresh every chunk) when the run pauses, ends, or in browse mode.
        force = state_changed and snap.state in ("paused", "finished", "stopped", "browse")
        # A closed loop moved keyframes and the map: redraw them at once, whatever the policy.
        force = force or (prev is not None and len(snap.loops or ()) != len(prev.loops or ()))
        # The 3D scene (map, cameras, trajectories) follows the map update policy, and shows at once
        # when tracking is lost or found: any scene message makes viser's page redraw (docs/viewer.md).
        if force or self.map_layer.follows(snap) or snap.tracking_lost != self.camera_layer.lost_shown:
            if self.map_layer.update(snap, force_consolidate=force) and self.first_map_at is None \
                    and snap.num_gaussians:
                self.first_map_at = time.monotonic()
            self.camera_layer.update(snap)
            self.loop_layer.update(snap)
            self.framing.update(snap)
        self.loop_layer.notify(self.server.get_clients().values(), snap)
        if prev is None or prev.map_version != snap.map_version or force:   # our renders follow
            for view in list(self.novel_views.values()):                    # every map version
                view.refresh()
        p = self.panels
        p.update_status(snap, self.map_layer.style)
        p.update_plots(snap)
        self.export_panel.follow(snap)
        if snap.live is not None and (prev is None or prev.live is not snap.live):
            p.update_live(snap)
        self.scrubber.update(snap)
        self.mesh_layer.sync(snap)
        self.updates += 1
        self.applied = snap      # fully pushed to viser (tests and the benchmark wait on this)
        return True

    # ------------------------------------------------------------------ our renderer
    def _render_map(self, intr: Intrinsics, w2c: np.ndarray, snap: MapSnapshot | None = None,
                    birth_limit: int | None = None):
        """Render the snapshot's map (Gaussians born up to the scrubbed keyframe) or None."""
        from splat_core.render import Renderer

        snap = snap or self._snapshot
        if snap is None or snap.num_gaussians == 0:
            return None
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

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        self.video_panel.cancel()
        self._stop.set()
        self._wake.set()
        self.refine_panel.close()
        self.renderer.stop()
        self._thread.join(timeout=5)
        self.renderer.join(timeout=30)


def build_viewer(server: viser.ViserServer, source, **kwargs) -> ViewerApp:
    """Build the GUI and scene on `server` and start pulling snapshots from `source`."""
    return ViewerApp(server, source, **kwargs)
