"""The GUI panel: run controls, status, plots, live images, keyframe scrubbing, export, help.

Builds the shared (server-scoped) GUI and updates it from snapshots. Callbacks are attached
by the ViewerApp; this module only lays out widgets and formats what they show.
"""

from __future__ import annotations

import numpy as np
import viser
import viser.uplot

from ..images import colorize_depth, colorize_silhouette, depth_max_of, mosaic, to_uint8
from ..snapshot import MAP_UPDATE_POLICIES, RUNNING_STYLES, MapSnapshot

PLOTS = (  # history key, title, colour
    ("tracking_loss", "Tracking loss", "#e87026"),
    ("ate_cm", "ATE so far (cm)", "#28aa5a"),
    ("psnr", "PSNR of the live render (dB)", "#3c6ee6"),
    ("seconds", "Seconds per frame", "#888888"),
)


def _placeholder(h: int = 120, w: int = 320) -> np.ndarray:
    return np.full((h, w, 3), 40, np.uint8)


def status_markdown(snap: MapSnapshot) -> str:
    if snap.state == "browse":
        lines = [f"**Browsing** {snap.message}", f"Gaussians: **{snap.num_gaussians:,}**",
                 f"Poses: {len(snap.estimated_c2w)} · keyframes: {len(snap.keyframes)}"]
        if snap.ate_cm is not None:
            lines.append(f"ATE: {snap.ate_cm:.2f} cm")
        return "  \n".join(lines)
    spf = f"{snap.seconds_per_frame:.2f} s/frame" if snap.seconds_per_frame is not None else "– s/frame"
    ate = f"{snap.ate_cm:.2f} cm" if snap.ate_cm is not None else "n/a"
    lines = [f"Frame **{snap.processed} / {snap.total_frames}** · {snap.state}",
             f"{spf} · Gaussians **{snap.num_gaussians:,}**",
             f"ATE so far: {ate} · keyframes: {len(snap.keyframes)}"]
    if snap.skipped_frames:
        index, reason = snap.skipped_frames[-1]
        lines.append(f"⚠ {len(snap.skipped_frames)} bad frame(s) skipped; last: {reason}")
    if snap.tracking_lost:
        first = next(k for k in range(len(snap.lost_frames) - 1, -1, -1)
                     if k == 0 or snap.lost_frames[k - 1] != snap.lost_frames[k] - 1)
        lines.append(f"⚠ **tracking lost at frame {snap.lost_frames[first]}, relocalising…** "
                     "(frames are not mapped until it is back)")
    elif snap.lost_frames:
        lines.append(f"⚠ tracking was lost on {len(snap.lost_frames)} frame(s) and recovered; last lost: "
                     f"frame {snap.lost_frames[-1]}")
    if snap.message:
        lines.append(snap.message)
    return "  \n".join(lines)


def live_mosaic(snap: MapSnapshot) -> np.ndarray | None:
    live = snap.live
    if live is None:
        return None
    dmax = depth_max_of(live.depth)
    top = [(to_uint8(live.color), f"captured #{live.frame_index}"),
           (colorize_depth(live.depth, dmax), "captured depth")]
    if live.render_color is not None:
        diff = np.abs(np.asarray(live.render_color) - _resize_like(live.color, live.render_color))
        top.append((to_uint8(np.clip(diff * 3.0, 0, 1)), "|error| x3"))
        psnr = f"render {live.psnr:.1f} dB" if live.psnr is not None else "render"
        bottom = [(to_uint8(live.render_color), psnr),
                  (colorize_depth(live.render_depth, dmax), "render depth"),
                  (colorize_silhouette(live.render_alpha), "silhouette")]
        return mosaic([top, bottom], tile_width=200)
    return mosaic([top], tile_width=200)


def _resize_like(img: np.ndarray, like: np.ndarray) -> np.ndarray:
    import cv2

    h, w = like.shape[:2]
    if img.shape[:2] == (h, w):
        return np.asarray(img)
    return cv2.resize(np.asarray(img, np.float32), (w, h), interpolation=cv2.INTER_AREA)


class Panels:
    def __init__(self, server: viser.ViserServer, help_markdown: str, has_controls: bool,
                 map_updates: str = "keyframes", browser_splats: int | None = None,
                 draw_while_running: str = "splats"):
        gui = server.gui
        self.server = server
        with gui.add_folder("Run", order=0):
            self.status = gui.add_markdown("Starting…")
            self.progress = gui.add_progress_bar(0.0, animated=False)
            self.pause_button = gui.add_button("Pause", icon=viser.Icon.PLAYER_PAUSE,
                                               visible=has_controls)
            self.resume_button = gui.add_button("Resume", icon=viser.Icon.PLAYER_PLAY,
                                                visible=has_controls, disabled=True)
            self.step_button = gui.add_button("Step one frame", icon=viser.Icon.PLAYER_TRACK_NEXT,
                                              visible=has_controls, disabled=True)
            self.frame_text = gui.add_text("Frames processed", "0", disabled=True)
            self.map_updates = gui.add_dropdown(
                "Map updates", MAP_UPDATE_POLICIES, initial_value=map_updates, visible=has_controls,
                hint="When the 3D view (splats, current camera, trajectory) follows SLAM: at each "
                     "keyframe, also between keyframes (costs a software-rendering browser much CPU), "
                     "or only when paused or finished")
            self.browser_splats = gui.add_number(
                "Splats while running", browser_splats or 0, min=0, step=1000, visible=has_controls,
                hint="0: the whole map. N: while SLAM runs, a thinned preview of at most about N larger "
                     "splats (the whole map when paused or finished), for a browser that draws WebGL in "
                     "software on the machine running SLAM")
            self.draw_while_running = gui.add_dropdown(
                "Draw while running", RUNNING_STYLES, initial_value=draw_while_running, visible=has_controls,
                hint="How the growing map is drawn while SLAM runs: splats, or a point per Gaussian (a fifth "
                     "or less of the cost for a browser that draws WebGL in software); splats when "
                     "paused or finished")
        with gui.add_folder("Live frame", order=1, visible=has_controls) as self.live_folder:
            self.live_image = gui.add_image(_placeholder(), format="jpeg", jpeg_quality=80)
        with gui.add_folder("Keyframes", order=2):
            self.keyframe_slider = gui.add_slider("Keyframe", min=0, max=1, step=1, initial_value=0,
                                                  disabled=True)
            self.follow_latest = gui.add_checkbox("Follow latest", initial_value=True)
            self.keyframe_info = gui.add_markdown("No keyframes yet.")
            self.keyframe_image = gui.add_image(_placeholder(), format="jpeg", jpeg_quality=80)
        with gui.add_folder("Plots", order=3, expand_by_default=has_controls):
            self.plots = {}
            for key, title, colour in PLOTS:
                self.plots[key] = gui.add_uplot(
                    data=(np.zeros(1), np.zeros(1)),
                    series=({"label": "frame"}, {"label": title, "stroke": colour, "width": 2}),
                    title=title, aspect=2.5)
        with gui.add_folder("Export", order=4) as self.export_folder:
            self.export_ply_button = gui.add_button("Download map.ply", icon=viser.Icon.DOWNLOAD)
            self.export_traj_button = gui.add_button("Download trajectory (TUM)", icon=viser.Icon.ROUTE)
            self.export_info = gui.add_markdown("Exports are also written into the run folder.")
        with gui.add_folder("Help", order=10, expand_by_default=False):
            gui.add_markdown(help_markdown)

    # ------------------------------------------------------------------ updates
    def update_status(self, snap: MapSnapshot) -> None:
        self.status.content = status_markdown(snap)
        total = max(snap.total_frames, 1)
        self.progress.value = 100.0 if snap.state == "browse" else 100.0 * snap.processed / total
        self.frame_text.value = str(max(snap.processed, 0))
        running = snap.state in ("starting", "running")
        paused = snap.state == "paused"
        self.pause_button.disabled = not running
        self.resume_button.disabled = not paused
        self.step_button.disabled = not paused

    def update_plots(self, snap: MapSnapshot) -> None:
        h = snap.history
        if not h or len(h.get("frame", ())) == 0:
            return
        x = np.asarray(h["frame"], np.float64)
        for key, handle in self.plots.items():
            y = np.asarray(h.get(key, np.full_like(x, np.nan)), np.float64)
            ok = np.isfinite(y)
            if ok.any():
                handle.data = (x[ok], y[ok])

    def update_live(self, snap: MapSnapshot) -> None:
        img = live_mosaic(snap)
        if img is not None:
            self.live_image.image = img
