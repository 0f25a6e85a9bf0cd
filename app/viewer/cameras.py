"""The 3D scene's cameras: keyframe frustums, trajectories and the current camera.

Keyframe frustums must not hide the map (issue 45: at frames 177-229 of 7-Scenes the default view
was a tunnel of 36-46 frustums with their images in front of the map). So:
- their size follows the map: a fraction of its extent, shrinking as keyframes multiply
  (`frustum_scale_for`), and every frustum is resized when that changes by a quarter;
- only the newest IMAGE_KEYFRAMES carry their images; the others are thin wireframes;
- they live under one `/keyframes` node, which the page's *Show keyframes* box hides.
"""

from __future__ import annotations

import threading

import numpy as np
import viser

from splat_core.camera import rotmat_to_quat

from ..snapshot import MapSnapshot

IMAGE_KEYFRAMES = 3          # the newest keyframes drawn with their images
FULL_SIZE_KEYFRAMES = 6      # up to this many keyframes, frustums have their full size
RESIZE_RATIO = 1.25          # frustums are resized when their size changes by more than this


def wxyz_position(c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c2w = np.asarray(c2w, np.float64)
    return rotmat_to_quat(c2w[:3, :3]), c2w[:3, 3].copy()


def trajectory_segments(c2w: np.ndarray) -> np.ndarray:
    """(T,4,4) poses -> (S,2,3) line segments between consecutive finite camera centres."""
    centres = np.asarray(c2w, np.float64)[:, :3, 3]
    centres = centres[np.all(np.isfinite(centres), axis=1)]
    if len(centres) < 2:
        return np.zeros((0, 2, 3), np.float32)
    return np.stack([centres[:-1], centres[1:]], axis=1).astype(np.float32)


def scene_extent(snap: MapSnapshot) -> float | None:
    """The map's size: the diagonal of the box holding 90% of its Gaussians along each axis (the
    trajectory's extent while there is no map); None when neither says anything yet."""
    means = np.asarray(snap.gaussians["means"])
    if len(means) >= 10:
        lo, hi = np.percentile(means, [5, 95], axis=0)
        return float(np.linalg.norm(hi - lo))
    if len(snap.estimated_c2w) >= 2:
        return float(np.ptp(np.asarray(snap.estimated_c2w)[:, :3, 3], axis=0).max())
    return None


def frustum_scale_for(extent: float | None, keyframes: int) -> float:
    """A keyframe frustum's size: 6% of the map's extent, shrinking with the square root of the
    number of keyframes past FULL_SIZE_KEYFRAMES (their total outline grows only as its root)."""
    if extent is None:
        return 0.1
    shrink = min(1.0, float(np.sqrt(FULL_SIZE_KEYFRAMES / max(keyframes, 1))))
    return float(np.clip(0.06 * extent * shrink, 0.005, 0.5))


class CameraLayer:
    """Keyframe frustums (the newest with thumbnails, clickable), trajectories and the current camera."""

    def __init__(self, server: viser.ViserServer, colors: dict, on_keyframe_click=None):
        self.server = server
        self.colors = colors
        self.on_keyframe_click = on_keyframe_click
        self.frustum_scale: float | None = None
        self.root = server.scene.add_frame("/keyframes", show_axes=False)
        self._frustums: dict[int, viser.CameraFrustumHandle] = {}
        self._with_image: set[int] = set()    # the frustums drawn with their images
        self._current = None
        self.lost_shown = False   # the current camera is drawn in the "lost" colour
        self._traj_drawn = {"estimated": b"", "reference": b""}   # the poses drawn (a loop moves old ones)
        self._lock = threading.RLock()

    @property
    def keyframe_frames(self) -> list[int]:
        return list(self._frustums)

    @property
    def image_frames(self) -> list[int]:
        return sorted(self._with_image)

    def set_keyframes_visible(self, visible: bool) -> None:
        """Show or hide every keyframe frustum (and the loop edges between them), for every page."""
        if self.root.visible != visible:
            self.root.visible = visible

    def _rescale(self, snap: MapSnapshot) -> float:
        scale = frustum_scale_for(scene_extent(snap), len(snap.keyframes))
        old = self.frustum_scale
        if old is None or not 1.0 / RESIZE_RATIO <= scale / old <= RESIZE_RATIO:
            self.frustum_scale = scale
            if old is not None:
                with self.server.atomic():
                    for handle in self._frustums.values():
                        handle.scale = scale
                    if self._current is not None:
                        self._current.scale = scale * 1.3
        return self.frustum_scale

    def update(self, snap: MapSnapshot) -> None:
        with self._lock:
            scale = self._rescale(snap)
            intr = snap.intrinsics
            fov = intr.fov_y if intr else np.deg2rad(55.0)
            aspect = intr.width / intr.height if intr else 4.0 / 3.0
            with_image = {kf.frame_index for kf in snap.keyframes[-IMAGE_KEYFRAMES:]}
            for kf in snap.keyframes:
                wxyz, pos = wxyz_position(kf.c2w)
                handle = self._frustums.get(kf.frame_index)
                if handle is None:
                    handle = self.server.scene.add_camera_frustum(
                        f"/keyframes/kf_{kf.frame_index:06d}", fov=fov, aspect=aspect, scale=scale,
                        thickness=1.0, thickness_units="screen", color=self._color_of(kf.frame_index),
                        format="jpeg", jpeg_quality=80, wxyz=wxyz, position=pos)
                    if self.on_keyframe_click is not None:
                        handle.on_click(lambda ev, f=kf.frame_index: self.on_keyframe_click(ev, f))
                    self._frustums[kf.frame_index] = handle
                elif not (np.allclose(handle.position, pos, atol=1e-6) and np.allclose(handle.wxyz, wxyz, atol=1e-7)):
                    handle.wxyz, handle.position = wxyz, pos      # moved by a loop correction: follow it
                self._show_image(handle, kf, kf.frame_index in with_image)
            self._update_trajectory("estimated", snap.estimated_c2w)
            if snap.reference_c2w is not None:
                self._update_trajectory("reference", snap.reference_c2w)
            if len(snap.estimated_c2w) and snap.state != "browse":
                wxyz, pos = wxyz_position(snap.estimated_c2w[-1])
                color = self.colors["lost"] if snap.tracking_lost else self.colors["current"]
                self.lost_shown = snap.tracking_lost
                if self._current is None:
                    self._current = self.server.scene.add_camera_frustum(
                        "/camera/current", fov=fov, aspect=aspect, scale=scale * 1.3,
                        thickness=3.0, thickness_units="screen", color=color,
                        wxyz=wxyz, position=pos)
                else:
                    self._current.wxyz, self._current.position, self._current.color = wxyz, pos, color

    def _show_image(self, handle, kf, wanted: bool) -> None:
        """The keyframe's image on its frustum (a newest one), or a thin outline (the others)."""
        if wanted == (kf.frame_index in self._with_image):
            return
        if wanted:
            handle.image, handle.thickness = kf.thumbnail, 1.5
            self._with_image.add(kf.frame_index)
        else:
            handle.image, handle.thickness = None, 1.0
            self._with_image.discard(kf.frame_index)

    def _update_trajectory(self, which: str, c2w: np.ndarray) -> None:
        drawn = np.ascontiguousarray(c2w, np.float64).tobytes()
        if drawn == self._traj_drawn[which]:
            return
        self._traj_drawn[which] = drawn
        seg = trajectory_segments(c2w)
        if len(seg) == 0:
            return
        self.server.scene.add_line_segments(
            f"/trajectory/{which}", seg, colors=np.array(self.colors[which], np.uint8),
            thickness=2.5 if which == "estimated" else 2.0, thickness_units="screen")

    def _color_of(self, frame_index: int):
        return self.colors["keyframe"]
