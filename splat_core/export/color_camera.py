"""Hand-offs of a two-camera capture describe the colour camera (docs/handoffs.md, "Two cameras").

A capture whose colour is registered to depth when read (a camera file with `color_intrinsics` /
`depth_to_color`, or a run registered from the capture's own estimate) has frames on the depth
camera's grid, and its run's poses are the depth camera's. COLMAP and nerfstudio train on the
images, so those hand-offs get the colour camera's own images as stored (not the registered ones),
its intrinsics, its poses and its depth:

    w2c_color = T_depth_to_color @ w2c_depth        (c2w_color = c2w_depth @ inv(T))
    depth     = the depth camera's depth seen from the colour camera (registration.depth_in_color_camera)

The world frame is unchanged, so seed points stay where they are. A registered capture (one camera)
is handed off as before.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..camera import Intrinsics
from ..registration import TwoCameras, depth_in_color_camera


def handoff_cameras(source) -> TwoCameras | None:
    """The two cameras a capture is registered with when read, or None (one camera)."""
    return getattr(source, "two_cameras", None) if source is not None else None


def color_camera_intrinsics(cams: TwoCameras) -> Intrinsics:
    """The colour camera at the size its images are stored at (the camera file's)."""
    return cams.color


def to_color_camera(frame, source, cams: TwoCameras, max_depth: float | None):
    """An export frame of the depth camera (registered colour, depth on its grid, its w2c) as the
    colour camera's: the colour image as stored, the depth seen from it and its w2c. The depth is
    the stored depth (cut at max_depth) sent through the z-buffer: the registered frame's depth has
    already lost the points its own z-test hid, a few more at low resolution."""
    color, depth = source.raw_pair(frame.source_index)
    kc = color_camera_intrinsics(cams)
    if color.shape[:2] != (kc.height, kc.width):   # the reader refuses this; kept as a guard for other sources
        kc = kc.scaled(color.shape[1], color.shape[0])
    if max_depth:
        depth = np.where(depth <= max_depth, depth, np.float32(0))
    depth_intr = source.intrinsics.scaled(depth.shape[1], depth.shape[0])
    depth = depth_in_color_camera(depth, depth_intr, cams, kc)
    return dataclasses.replace(frame, w2c=cams.matrix @ np.asarray(frame.w2c, np.float64),
                               color=np.asarray(color, np.float32), depth=depth)
