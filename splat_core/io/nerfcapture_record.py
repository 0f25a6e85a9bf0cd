"""Recording phone frames as a capture folder in SplaTAM's NeRFCapture layout.

What SplaTAM's scripts/nerfcapture2dataset.py writes, which `NeRFCaptureCapture` reads back:
rgb/<i>.png (8-bit RGB as sent), depth/<i>.png (uint16 = metres * 65535 / 10, nearest-upsampled
to the colour size), transforms.json with the first frame's fl_x fl_y cx cy w h and
integer_depth_scale at the top, and per frame file_path, depth_path, transform_matrix (the
app's camera-to-world, row-major, ARKit axes as sent), its intrinsics and its timestamp (which
SplaTAM's script leaves out). Depth beyond 10 m, NaN or inf becomes 0 (invalid) instead of
wrapping around as the script's plain uint16 cast does.

Crash safety: each frame's images are written (atomically) before transforms.json lists them,
and transforms.json is rewritten atomically after every frame, so whatever happens the folder
is a readable capture of every frame it lists.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import write_bytes_atomic, write_text_atomic
from .images import depth_to_units, encode_png
from .nerfcapture import DEFAULT_METRES_PER_UNIT
from .nerfcapture_dds import PhoneFrame

UNITS_PER_METRE = 1.0 / DEFAULT_METRES_PER_UNIT   # as NeRFCaptureCapture computes it from integer_depth_scale


def upsample_nearest(depth: np.ndarray, width: int, height: int) -> np.ndarray:
    import cv2

    if depth.shape == (height, width):
        return depth
    return cv2.resize(depth, (width, height), interpolation=cv2.INTER_NEAREST)


class CaptureRecorder:
    """Appends PhoneFrames to a capture folder (created with the first frame; must be new or empty)."""

    def __init__(self, root):
        self.root = Path(root)
        if self.root.exists() and (not self.root.is_dir() or any(self.root.iterdir())):
            raise InputError(f"{self.root}: already exists and is not empty; record into a new folder")
        self.frames: list[dict] = []
        self.size: tuple[int, int] | None = None

    def __len__(self) -> int:
        return len(self.frames)

    def add(self, f: PhoneFrame) -> tuple[int, np.ndarray]:
        """Write frame f; returns (its index, the depth units as written, at the colour size)."""
        w, h = f.size
        if self.size is not None and (w, h) != self.size:
            raise ValueError(f"frame {f.id}: image is {w}x{h}, the first frame was {self.size[0]}x{self.size[1]}")
        i = len(self.frames)
        units, _ = depth_to_units(upsample_nearest(f.depth, w, h), UNITS_PER_METRE)
        rgb_rel, depth_rel = f"rgb/{i}.png", f"depth/{i}.png"
        write_bytes_atomic(self.root / rgb_rel, encode_png(f.rgb, str(self.root / rgb_rel)))
        write_bytes_atomic(self.root / depth_rel, encode_png(units, str(self.root / depth_rel)))
        intr = dict(fl_x=f.fl_x, fl_y=f.fl_y, cx=f.cx, cy=f.cy, w=w, h=h)
        self.frames.append(dict(file_path=rgb_rel, depth_path=depth_rel, transform_matrix=f.c2w_arkit.tolist(),
                                timestamp=f.timestamp, **intr))
        if self.size is None:
            self.size, self._top = (w, h), dict(intr, integer_depth_scale=DEFAULT_METRES_PER_UNIT)
        write_text_atomic(self.root / "transforms.json", json.dumps(dict(self._top, frames=self.frames), indent=1))
        return i, units
