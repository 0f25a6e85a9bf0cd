"""Frame: one RGB-D observation, the unit every reader yields and the engine consumes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .intrinsics import Intrinsics


@dataclass
class Frame:
    """One RGB-D frame.

    color: HxWx3 float32 in [0, 1] (as stored, no gamma).
    depth: HxW float32 metres, 0 = invalid.
    intrinsics: for this colour/depth resolution.
    c2w_ref: optional 4x4 reference pose (camera-to-world, OpenCV axes) in the capture's frame.
    """

    index: int
    timestamp: float
    color: np.ndarray
    depth: np.ndarray
    intrinsics: Intrinsics
    c2w_ref: np.ndarray | None = None

    @property
    def height(self) -> int:
        return self.depth.shape[0]

    @property
    def width(self) -> int:
        return self.depth.shape[1]


def resize_frame(frame: Frame, width: int, height: int) -> Frame:
    """Bring a frame to a working resolution: colour by area averaging, depth by nearest
    neighbour (never blend depth across edges), intrinsics scaled to match."""
    if (frame.width, frame.height) == (width, height):
        return frame
    intr = frame.intrinsics.scaled(width, height)
    color = resize_to(frame.color, intr, False)
    depth = resize_to(frame.depth, intr, True)
    return Frame(frame.index, frame.timestamp, np.clip(color, 0.0, 1.0).astype(np.float32),
                 depth.astype(np.float32), intr, frame.c2w_ref)


def resize_to(image: np.ndarray, intr: Intrinsics, nearest: bool) -> np.ndarray:
    """An image at `intr`'s size: nearest neighbour for depth and masks (never blend depth across
    edges); otherwise area averaging when shrinking, bilinear when enlarging."""
    import cv2

    if image.shape[:2] == (intr.height, intr.width):
        return image
    if nearest:
        mode = cv2.INTER_NEAREST
    else:
        mode = cv2.INTER_AREA if intr.width < image.shape[1] else cv2.INTER_LINEAR
    return cv2.resize(image, (intr.width, intr.height), interpolation=mode)
