"""Keyframe scrubbing, per visitor: each page has its own Keyframes panel and its own view of the map.

    scrubber = KeyframeScrubber(server, map_layer, camera_layer, renderer, render_map)
    scrubber.attach(client)          # on_client_connect: the page's Keyframes panel, following the latest
    scrubber.update(snap)            # every applied snapshot: slider range, follow, new chunks
    scrubber.go_to(client_id, pos)   # what the slider, the number box and a frustum click do

The slider counts keyframes from 1 (slider value v is keyframe position v - 1; the label says
"Keyframe v / K"), so the slider, its number box, the label and the highlighted frustum agree.
Going to a keyframe, for that page only:
- the map shows as it was at that keyframe: the chunks born after it are hidden by client-scoped
  shadows (a hidden node under the same name shadows the shared node for one client, viser 1.1.1),
- the keyframe frustums with their images (which would fill the view from a keyframe's pose)
  are hidden and drawn as faint outlines instead, still clickable; the one at the keyframe is left out;
  the loop edges with them, and edges of the loops closed by that keyframe drawn for the page alone,
- the camera flies to the keyframe's pose, and the panel shows the captured image beside our
  render of the map at that keyframe from that pose (cached per (keyframe, run state), so ten
  visitors on the same keyframe cost one render, and a growing map does not re-render it).
Other pages are untouched: a new page follows the latest map, whatever another visitor scrubbed to.
"""

from __future__ import annotations

import threading

import numpy as np
import viser

from splat_core.camera import Intrinsics, invert_pose
from splat_core.metrics import psnr

from ..images import colorize_depth, depth_max_of, mosaic, to_uint8
from ..snapshot import MapSnapshot
from .loops import LOOP_COLOR, loop_segments
from .cameras import wxyz_position
from .page_camera import place_c2w

FADED_COLOR = (150, 150, 160)


def _placeholder(h: int = 120, w: int = 320) -> np.ndarray:
    return np.full((h, w, 3), 40, np.uint8)


def keyframe_title(pos: int, snap: MapSnapshot) -> str:
    kf = snap.keyframes[pos]
    return f"Keyframe {pos + 1} / {len(snap.keyframes)} (frame #{kf.frame_index})"


def keyframe_panel(pos: int, snap: MapSnapshot, render_map, width: int) -> tuple[np.ndarray, str]:
    """(image, markdown) of the Keyframes panel at position `pos`: captured | render | render depth."""
    kf = snap.keyframes[pos]
    title = keyframe_title(pos, snap)
    if kf.color is None or snap.intrinsics is None:
        return kf.thumbnail, title
    intr: Intrinsics = snap.intrinsics
    if intr.width > width:
        intr = intr.scaled(width, max(1, round(intr.height * width / intr.width)))
    out = render_map(intr, invert_pose(kf.c2w), snap=snap, birth_limit=kf.frame_index)
    captured = np.asarray(kf.color, np.float32)
    if captured.shape[1] != intr.width:
        import cv2
        captured = cv2.resize(captured, (intr.width, intr.height), interpolation=cv2.INTER_AREA)
    tiles = [to_uint8(captured)]
    text = title + "  \nLeft: the captured image."
    if out is not None:
        color = out.color.detach().cpu().numpy()
        value = psnr(color, captured)
        depth = out.depth.detach().cpu().numpy()
        tiles += [to_uint8(color), colorize_depth(depth, depth_max_of(kf.depth, depth))]
        text = (title + f"  \nLeft to right: captured · our render of the map at this keyframe "
                f"(**{value:.2f} dB** PSNR) · its depth")
    return mosaic([[(t, "") for t in tiles]], tile_width=200), text


class ClientScrub:
    """One page's Keyframes panel and what it shows."""

    def __init__(self, client, order: int = 2):
        self.client = client
        gui = client.gui
        with gui.add_folder("Keyframes", order=order):
            self.slider = gui.add_slider("Keyframe", min=1, max=2, step=1, initial_value=1, disabled=True,
                                         hint="Go to keyframe N: the map as it was then, seen from its pose "
                                              "(this page only)")
            self.follow = gui.add_checkbox("Follow latest", initial_value=True,
                                           hint="Show the live map and the newest keyframe (this page only)")
            self.info = gui.add_markdown("No keyframes yet.")
            self.image = gui.add_image(_placeholder(), format="jpeg", jpeg_quality=80)
        self.position: int | None = None       # keyframe position shown, None = following the latest
        self.shown_key = None                  # (position, map_version) whose panel image is shown
        self.programmatic = 0
        self.shadows: dict[str, object] = {}   # scene name -> client-scoped node
        self.lock = threading.RLock()


class KeyframeScrubber:
    def __init__(self, server: viser.ViserServer, map_layer, camera_layer, renderer, render_map, *,
                 width: int = 320, on_change=None):
        self.server = server
        self.map_layer = map_layer
        self.camera_layer = camera_layer
        self.renderer = renderer
        self.render_map = render_map               # render_map(intr, w2c, snap=, birth_limit=) -> Render | None
        self.width = width
        self.on_change = on_change                 # on_change(client_id): the page's view changed
        self.pages: dict[int, ClientScrub] = {}
        self.snapshot: MapSnapshot | None = None
        self._panel_cache: dict = {}               # (position, map_version) -> (image, text)
        self._lock = threading.RLock()

    # ------------------------------------------------------------------ pages
    def attach(self, client) -> ClientScrub:
        page = ClientScrub(client)
        cid = client.client_id
        page.slider.on_update(lambda _e: self._on_slider(cid))
        page.follow.on_update(lambda _e: self._on_follow(cid))
        with self._lock:
            self.pages[cid] = page
        if self.snapshot is not None:
            self._sync_page(page, self.snapshot)
        return page

    def detach(self, client_id: int) -> None:
        with self._lock:
            self.pages.pop(client_id, None)

    def position_of(self, client_id: int) -> int | None:
        page = self.pages.get(client_id)
        return None if page is None else page.position

    def birth_limit(self, client_id: int) -> int | None:
        """The last frame whose Gaussians the page shows (None: the whole map)."""
        pos, snap = self.position_of(client_id), self.snapshot
        if pos is None or snap is None or not snap.keyframes:
            return None
        return snap.keyframes[min(pos, len(snap.keyframes) - 1)].frame_index

    # ------------------------------------------------------------------ snapshots
    def update(self, snap: MapSnapshot) -> None:
        self.snapshot = snap
        for page in list(self.pages.values()):
            self._sync_page(page, snap)

    def _sync_page(self, page: ClientScrub, snap: MapSnapshot) -> None:
        K = len(snap.keyframes)
        if K == 0:
            return
        with page.lock:
            page.programmatic += 1
            try:
                if page.slider.max != max(K, 2):
                    page.slider.max = max(K, 2)
                if page.slider.disabled != (K < 2):
                    page.slider.disabled = K < 2
                if page.position is None and page.slider.value != K:
                    page.slider.value = K
            finally:
                page.programmatic -= 1
            if page.position is not None:
                self._shadow(page, page.position, snap)     # chunks and frustums that arrived since
        self._show_panel(page, K - 1 if page.position is None else page.position, snap)

    # ------------------------------------------------------------------ callbacks
    def _on_slider(self, cid: int) -> None:
        page = self.pages.get(cid)
        snap = self.snapshot
        if page is None or page.programmatic or snap is None or not snap.keyframes:
            return
        self.go_to(cid, int(page.slider.value) - 1)

    def _on_follow(self, cid: int) -> None:
        page = self.pages.get(cid)
        if page is None or page.programmatic:
            return
        if page.follow.value:
            self.go_to(cid, None)
        elif page.position is None and self.snapshot is not None and self.snapshot.keyframes:
            self.go_to(cid, len(self.snapshot.keyframes) - 1)

    def on_frustum_click(self, event, frame_index: int) -> None:
        snap = self.snapshot
        client = getattr(event, "client", None)
        if snap is None or client is None:
            return
        frames = [kf.frame_index for kf in snap.keyframes]
        if frame_index in frames:
            self.go_to(client.client_id, frames.index(frame_index))

    def go_to(self, cid: int, pos: int | None, fly: bool = True) -> None:
        """Page `cid` shows keyframe position `pos` (None: follow the latest map again)."""
        page, snap = self.pages.get(cid), self.snapshot
        if page is None or snap is None:
            return
        K = len(snap.keyframes)
        if pos is not None:
            pos = int(np.clip(pos, 0, K - 1)) if K else None
        with page.lock:
            page.position = pos
            page.programmatic += 1
            try:   # slider, number box, label and checkbox agree, whoever moved first
                if page.follow.value != (pos is None):
                    page.follow.value = pos is None
                target = K if pos is None else pos + 1
                if K and page.slider.value != target:
                    page.slider.value = target
            finally:
                page.programmatic -= 1
            if pos is None:
                self._unshadow(page)
            else:
                self._shadow(page, pos, snap)
        if pos is not None and fly:
            place_c2w(page.client, snap.keyframes[pos].c2w)
        if K:
            self._show_panel(page, K - 1 if pos is None else pos, snap)
        if self.on_change is not None:
            self.on_change(cid)

    # ------------------------------------------------------------------ the page's scene
    def _shadow(self, page: ClientScrub, pos: int, snap: MapSnapshot) -> None:
        """Hide, for this page only, the chunks born after keyframe `pos` and the frustum images."""
        names = self.map_layer.chunk_names()
        want = {n: "hidden" for k, n in enumerate(names) if k > pos}
        want["/keyframes"] = "hidden"
        frames = [kf.frame_index for kf in snap.keyframes]
        for k, frame in enumerate(frames):
            if k != pos:
                want[f"/scrub/kf_{frame:06d}"] = frame
        seg = loop_segments(snap.loops, snap.keyframes, upto_frame=frames[pos])   # loops closed by then
        if len(seg):
            want["/scrub/loops"] = seg
        scene = page.client.scene
        for name in [n for n in page.shadows if n not in want
                     or (n == "/scrub/loops" and not np.array_equal(page.shadows[n].points, want[n]))]:
            page.shadows.pop(name).remove()
        for name, what in want.items():
            if name in page.shadows:
                if name.startswith("/scrub/kf_"):   # a loop correction moved the keyframe: follow it
                    self._follow_pose(page.shadows[name], snap.keyframes[frames.index(what)].c2w)
                continue
            if name == "/scrub/loops":
                page.shadows[name] = scene.add_line_segments(name, what, colors=np.array(self._loop_color(), np.uint8),
                                                             thickness=2.0, thickness_units="screen")
            elif what == "hidden":
                page.shadows[name] = scene.add_frame(name, show_axes=False, visible=False)
            else:
                page.shadows[name] = self._faded_frustum(scene, name, snap, frames.index(what))

    def _loop_color(self):
        return (getattr(self.camera_layer, "colors", None) or {}).get("loop", LOOP_COLOR)

    @staticmethod
    def _follow_pose(handle, c2w) -> None:
        wxyz, pos = wxyz_position(c2w)
        if not (np.allclose(handle.position, pos, atol=1e-6) and np.allclose(handle.wxyz, wxyz, atol=1e-7)):
            handle.wxyz, handle.position = wxyz, pos

    def _faded_frustum(self, scene, name: str, snap: MapSnapshot, k: int):
        kf = snap.keyframes[k]
        intr = snap.intrinsics
        wxyz, pos = wxyz_position(kf.c2w)
        handle = scene.add_camera_frustum(
            name, fov=intr.fov_y if intr else np.deg2rad(55.0),
            aspect=intr.width / intr.height if intr else 4.0 / 3.0,
            scale=self.camera_layer.frustum_scale or 0.1, thickness=1.0, thickness_units="screen",
            color=FADED_COLOR, wxyz=wxyz, position=pos)
        handle.on_click(lambda ev, f=kf.frame_index: self.on_frustum_click(ev, f))
        return handle

    def _unshadow(self, page: ClientScrub) -> None:
        for name in list(page.shadows):
            page.shadows.pop(name).remove()

    # ------------------------------------------------------------------ the panel
    def _show_panel(self, page: ClientScrub, pos: int, snap: MapSnapshot) -> None:
        # not per map version: a render per snapshot would take the CPU SLAM needs; a new keyframe,
        # or the run pausing / ending, re-renders (one render for every page on the same key)
        key = (pos, snap.keyframes[pos].frame_index, snap.state)
        if page.shown_key == key:
            return
        page.shown_key = key
        page.info.content = keyframe_title(pos, snap) + " · rendering…"

        def job():
            cached = self._panel_cache.get(key)
            if cached is None:
                cached = keyframe_panel(pos, snap, self.render_map, self.width)
                self._panel_cache = {key: cached}      # the newest only: pages mostly agree
            if page.shown_key == key:
                page.image.image, page.info.content = cached
        self.renderer.submit(("keyframe", page.client.client_id), job)
