"""Measuring in the viewer: click two points on the map, see the distance in metres.

A click gives a ray from the browser camera (viser's scene click: origin and direction in world
coordinates). `pick_point` finds the pixel of that ray in the browser camera's image, renders
the map's depth at that one pixel with our renderer (`render_pixels`), and walks that far along
the ray: the point lies where the rendered surface is, whatever the WebGL view showed. Depth is
the alpha-weighted z of the Gaussians (docs/design.md, the renderer contract), so the surface depth is depth / alpha; a
pixel that the map barely covers (alpha < `min_alpha`) has no point.

The tool (`MeasureTool`) keeps the clicked points: the second one draws a line and a label with
the distance; a third click starts a new measurement.
"""

from __future__ import annotations

import threading

import numpy as np
import viser

from splat_core.camera import Intrinsics, invert_pose

from .novel_view import browser_camera


def pick_point(gaussians, c2w: np.ndarray, intrinsics: Intrinsics, ray_direction, *, renderer,
               min_alpha: float = 0.5) -> np.ndarray | None:
    """The world point (metres) where the ray from the camera centre along `ray_direction`
    (world axes) meets the rendered map, or None when it misses the map or leaves the image."""
    import torch

    c2w = np.asarray(c2w, np.float64)
    d_cam = c2w[:3, :3].T @ np.asarray(ray_direction, np.float64)
    if d_cam[2] <= 1e-9:
        return None
    u = intrinsics.fx * d_cam[0] / d_cam[2] + intrinsics.cx
    v = intrinsics.fy * d_cam[1] / d_cam[2] + intrinsics.cy
    px, py = int(round(u)), int(round(v))
    if not (0 <= px < intrinsics.width and 0 <= py < intrinsics.height):
        return None
    w2c = torch.as_tensor(invert_pose(c2w), dtype=torch.float32)
    with torch.no_grad():
        out = renderer.pixels(renderer.visible(gaussians, intrinsics, w2c), intrinsics, w2c, np.array([[px, py]]))
    alpha = float(out.alpha[0])
    if alpha < min_alpha:
        return None
    z = float(out.depth[0]) / alpha
    return c2w[:3, 3] + np.asarray(ray_direction, np.float64) * (z / d_cam[2])


class MeasureTool:
    """GUI folder "Measure" and the clicked points in the scene under /measure."""

    COLOR = (255, 200, 0)

    def __init__(self, server: viser.ViserServer, snapshot_fn, render_backend: str = "auto", order: float = 6.5):
        self.server = server
        self.snapshot_fn = snapshot_fn      # () -> MapSnapshot | None (immutable numpy arrays)
        self.render_backend = render_backend
        self.points: list[np.ndarray] = []
        self.distance: float | None = None
        self._lock = threading.Lock()
        self._listening = False
        gui = server.gui
        with gui.add_folder("Measure", order=order, expand_by_default=False):
            self.enabled = gui.add_checkbox("Click to measure", initial_value=False,
                                            hint="click two points on the map; a third click starts again")
            self.info = gui.add_markdown("Tick the box, then click two points on the map.")
            self.clear_button = gui.add_button("Clear measurement")
        self.enabled.on_update(lambda _: self._set_enabled(self.enabled.value))
        self.clear_button.on_click(lambda _: self.clear())

    def _set_enabled(self, on: bool) -> None:
        with self._lock:
            if on and not self._listening:
                self.server.scene.on_click()(self._on_click)
            elif not on and self._listening:
                self.server.scene.remove_click_callback(self._on_click)
            self._listening = on

    def _on_click(self, event) -> None:
        intr, w2c = browser_camera(event.client, max_width=1 << 16)   # the canvas at full size
        self.click(invert_pose(w2c), intr, event.ray_direction)

    def _gaussians(self):
        from ..video import gaussians_of

        snap = self.snapshot_fn()
        if snap is None or snap.num_gaussians == 0:
            return None, None
        return gaussians_of(snap.gaussians), snap.near_plane

    def click(self, c2w: np.ndarray, intrinsics: Intrinsics, ray_direction) -> np.ndarray | None:
        """One click: the picked point (None on a miss, which changes nothing)."""
        from splat_core.render import Renderer

        with self._lock:
            gaussians, near = self._gaussians()
            if gaussians is None:
                self.info.content = "No map to measure yet."
                return None
            point = pick_point(gaussians, c2w, intrinsics, ray_direction,
                               renderer=Renderer(near, self.render_backend))
            if point is None:
                self.info.content = "That click missed the map; click on a surface."
                return None
            if len(self.points) >= 2:
                self.points = []
            self.points.append(point)
            self.distance = float(np.linalg.norm(self.points[1] - self.points[0])) if len(self.points) == 2 else None
            self._draw()
            return point

    def clear(self) -> None:
        with self._lock:
            self.points, self.distance = [], None
            self._draw()

    def _draw(self) -> None:
        scene = self.server.scene
        scene.remove_by_name("/measure")
        if not self.points:
            self.info.content = "Tick the box, then click two points on the map."
            return
        pts = np.asarray(self.points, np.float32)
        scene.add_point_cloud("/measure/points", pts, self.COLOR, point_size=0.02, point_shape="circle",
                              precision="float32")
        if self.distance is None:
            self.info.content = f"Point 1 at {_fmt(pts[0])}; click the second point."
            return
        scene.add_line_segments("/measure/line", pts[None], self.COLOR, thickness=3.0, thickness_units="screen")
        scene.add_label("/measure/label", f"{self.distance:.3f} m", position=tuple(pts.mean(axis=0)))
        self.info.content = (f"Distance: **{self.distance:.3f} m**  \n{_fmt(pts[0])} → {_fmt(pts[1])}  \n"
                             "A third click starts a new measurement.")


def _fmt(p) -> str:
    return "(" + ", ".join(f"{v:.3f}" for v in p) + ") m"
