"""Small synthetic sources and maps for the engine's unit tests (ray-cast, independent of our renderer)."""

from __future__ import annotations

import numpy as np

from splat_core.camera import invert_pose
from splat_core.config import DensifyConfig
from splat_core.densify import gaussians_from_pixels
from splat_core.synthetic import SyntheticSource


def small_source(n=12, w=80, h=60, **kw):
    return SyntheticSource(n_frames=n, width=w, height=h, seed=3, **kw)


def map_from_frame(frame, w2c=np.eye(4)):
    mask = frame.depth > 0
    return gaussians_from_pixels(frame.color, frame.depth, mask, frame.intrinsics, w2c, 0, DensifyConfig(), True)


def rel_w2c(src, i):
    """Reference w2c of frame i in the world of frame 0 (the SLAM world)."""
    return invert_pose(invert_pose(src[0].c2w_ref) @ src[i].c2w_ref)
