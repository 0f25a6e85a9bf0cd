"""The GUI panels: status, plots, live images and help on every page; the run controls on the pages
of visitors who may control the run (a ControlGui). Keyframes: scrub.py; export: export_panel.py.

Callbacks are attached by the ViewerApp; this module only lays out widgets and formats what they show.
The plots: plots.py.
"""

from __future__ import annotations

import numpy as np
import viser

from ..images import colorize_depth, colorize_silhouette, depth_max_of, mosaic, to_uint8
from ..snapshot import LIVE_TILE_WIDTH, MAP_UPDATE_POLICIES, RUNNING_STYLES, MapSnapshot
from .loops import loop_count_text, loop_status_lines
from .plots import PlotsPanel


def _placeholder(h: int = 120, w: int = 320) -> np.ndarray:
    return np.full((h, w, 3), 40, np.uint8)


def status_markdown(snap: MapSnapshot, map_style: str = "splats") -> str:
    """The status text; `map_style`: how the 3D view draws the map now (MapLayer.style)."""
    if snap.state == "browse":
        lines = [f"**Browsing** {snap.message}", f"Gaussians: **{snap.num_gaussians:,}**",
                 f"Poses: {len(snap.estimated_c2w)} · keyframes: {len(snap.keyframes)}{loop_count_text(snap.loops)}"]
        if snap.ate_cm is not None:
            lines.append(f"ATE: {snap.ate_cm:.2f} cm")
        return "  \n".join(lines + loop_status_lines(snap.loops))
    if snap.state in ("starting", "running") and snap.num_gaussians == 0:   # no map yet (live: mapping lags)
        return "  \n".join(first_frame_lines(snap))
    spf = f"{snap.seconds_per_frame:.2f} s/frame" if snap.seconds_per_frame is not None else "– s/frame"
    ate = f"{snap.ate_cm:.2f} cm" if snap.ate_cm is not None else "n/a (no reference poses)"
    ended = snap.state in ("finished", "stopped", "error")
    lines = [f"Frame **{snap.processed} / {snap.total_frames}** · {STATE_WORDS.get(snap.state, snap.state)}",
             f"{spf} · Gaussians **{snap.num_gaussians:,}**",
             f"{'ATE' if ended else 'ATE so far'}: {ate} · keyframes: {len(snap.keyframes)}"
             f"{loop_count_text(snap.loops)}"] + loop_status_lines(snap.loops)
    if snap.received is not None:
        received, dropped = snap.received
        lines.append(f"Frames received: {received} · processed {received - dropped} · dropped **{dropped}**")
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
    if map_style == "points" and snap.state == "running":
        lines.append("The map is drawn as points while SLAM runs (a page without a GPU is open), as splats "
                     "once it pauses or ends")
    if snap.message:
        lines.append(snap.message)
    return "  \n".join(lines)


STATE_WORDS = {"starting": "starting", "running": "running", "paused": "paused",
               "finished": "**finished**: the run folder is written", "stopped": "stopped: the run folder is written",
               "error": "**error**"}


def first_frame_lines(snap: MapSnapshot) -> list[str]:
    """What the page says before the first frame is done (on a first run the message is the kernel
    compile's progress: app/warmup.py KernelCompile, through the worker)."""
    lines = [f"**Processing frame {max(snap.processed, 1)} / {snap.total_frames or '…'}** · {snap.state}"]
    lines.append(snap.message or "the first frame builds the map from scratch; the 3D view fills in after it")
    return lines


def live_caption(snap: MapSnapshot) -> str:
    """Page text above the live images (labels drawn into the images were unreadable when scaled)."""
    live = snap.live
    if live is None:
        return "Waiting for the first frame…"
    top = f"**Frame #{live.frame_index}**. Top: captured colour · captured depth"
    if live.render_color is None:
        return top + " (our render of the map appears once there is a map)."
    psnr = f" ({live.psnr:.1f} dB PSNR)" if live.psnr is not None else ""
    return (top + " · error (|render - captured| x3, bright = wrong).  \n"
            f"Bottom: our render from the tracked pose{psnr} · its depth · silhouette (white = covered).")


def live_mosaic(snap: MapSnapshot) -> np.ndarray | None:
    live = snap.live
    if live is None:
        return None
    dmax = depth_max_of(live.depth)
    top = [(to_uint8(live.color), ""), (colorize_depth(live.depth, dmax), "")]
    if live.render_color is not None:
        diff = np.abs(np.asarray(live.render_color) - _resize_like(live.color, live.render_color))
        top.append((to_uint8(np.clip(diff * 3.0, 0, 1)), ""))
        bottom = [(to_uint8(live.render_color), ""),
                  (colorize_depth(live.render_depth, dmax), ""),
                  (colorize_silhouette(live.render_alpha), "")]
        return mosaic([top, bottom], tile_width=LIVE_TILE_WIDTH)
    return mosaic([top], tile_width=LIVE_TILE_WIDTH)


def _resize_like(img: np.ndarray, like: np.ndarray) -> np.ndarray:
    import cv2

    h, w = like.shape[:2]
    if img.shape[:2] == (h, w):
        return np.asarray(img)
    return cv2.resize(np.asarray(img, np.float32), (w, h), interpolation=cv2.INTER_AREA)


class Panels:
    """The shared panels (status, live frame, plots, help: every page) and the run controls (built
    on `controls`, a ControlGui: the pages of visitors who may control the run)."""

    def __init__(self, server: viser.ViserServer, help_markdown: str, has_controls: bool,
                 map_updates: str = "keyframes", browser_splats: int | None = None,
                 draw_while_running: str = "auto", controls=None):
        gui = server.gui
        self.server = server
        with gui.add_folder("Run", order=0):
            self.status = gui.add_markdown("Starting…")
            self.progress = gui.add_progress_bar(0.0, animated=False)
            self.frame_text = gui.add_text("Frames processed", "0", disabled=True)
            self.show_keyframes = gui.add_checkbox(
                "Show keyframes", True, hint="The keyframe cameras in the 3D view (the newest few with their "
                                             "images) and the loop edges between them, for every visitor")
        cgui = controls if controls is not None else gui
        with cgui.add_folder("Run controls (shared by every visitor)", order=0.5, visible=has_controls):
            self.pause_button = cgui.add_button("Pause", icon=viser.Icon.PLAYER_PAUSE, visible=has_controls,
                                                hint="Pause SLAM after this frame (for every visitor)")
            self.resume_button = cgui.add_button("Resume", icon=viser.Icon.PLAYER_PLAY,
                                                 visible=has_controls, disabled=True,
                                                 hint="Go on with SLAM (for every visitor)")
            self.step_button = cgui.add_button("Step one frame", icon=viser.Icon.PLAYER_TRACK_NEXT,
                                               visible=has_controls, disabled=True,
                                               hint="Process the next frame, then pause again (for every visitor)")
            self.map_updates = cgui.add_dropdown(
                "Map updates", MAP_UPDATE_POLICIES, initial_value=map_updates, visible=has_controls,
                hint="When the 3D view (splats, current camera, trajectory) follows SLAM: at each "
                     "keyframe, also between keyframes (costs a software-rendering browser much CPU), "
                     "or only when paused or finished")
            self.browser_splats = cgui.add_number(
                "Splats while running", browser_splats or 0, min=0, step=1000, visible=has_controls,
                hint="0 (the default): the whole map. N: while SLAM runs, a thinned preview of at most about "
                     "N larger splats (the whole map when paused or finished), for a browser that draws WebGL in "
                     "software on the machine running SLAM")
            self.draw_while_running = cgui.add_dropdown(
                "Draw while running", RUNNING_STYLES, initial_value=draw_while_running, visible=has_controls,
                hint="How the growing map is drawn while SLAM runs: splats, or a point per Gaussian (a tenth "
                     "of the cost for a browser that draws WebGL in software); auto: points while such a "
                     "browser has the page open, splats otherwise; splats when paused or finished")
        with gui.add_folder("Live frame", order=1, visible=has_controls) as self.live_folder:
            self.live_caption = gui.add_markdown("Waiting for the first frame…")
            self.live_image = gui.add_image(_placeholder(), format="jpeg", jpeg_quality=80)
        self.plots = PlotsPanel(gui, order=3, expanded=has_controls)
        with gui.add_folder("Help", order=10, expand_by_default=False):
            gui.add_markdown(help_markdown)

    # ------------------------------------------------------------------ updates
    def show_preview(self, color: np.ndarray, depth: np.ndarray, frame_index: int = 0) -> None:
        """The capture's first images at once, before SLAM has processed them."""
        self.live_image.image = mosaic([[(to_uint8(color), ""), (colorize_depth(depth), "")]],
                                       tile_width=LIVE_TILE_WIDTH)
        self.live_caption.content = (f"**Frame #{frame_index}** as captured: colour · depth. SLAM is processing "
                                     "it; our render of the map appears below it after the first frame.")

    def update_status(self, snap: MapSnapshot, map_style: str = "splats") -> None:
        self.status.content = status_markdown(snap, map_style)
        total = max(snap.total_frames, 1)
        self.progress.value = 100.0 if snap.state == "browse" else 100.0 * snap.processed / total
        self.frame_text.value = str(max(snap.processed, 0))
        running = snap.state in ("starting", "running")
        paused = snap.state == "paused"
        for button, disabled in ((self.pause_button, not running), (self.resume_button, not paused),
                                 (self.step_button, not paused)):
            if button.disabled != disabled:
                button.disabled = disabled

    def update_plots(self, snap: MapSnapshot) -> None:
        no_reference = snap.ate_cm is None and snap.processed > 0
        self.plots.update(snap.history, {"ate_cm": "n/a (no reference poses)"} if no_reference else None)

    def update_live(self, snap: MapSnapshot) -> None:
        img = live_mosaic(snap)
        if img is not None:
            self.live_image.image = img
        caption = live_caption(snap)
        if self.live_caption.content != caption:
            self.live_caption.content = caption
