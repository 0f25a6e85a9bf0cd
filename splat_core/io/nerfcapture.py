"""NeRFCapture (iPhone) offline export as read by SplaTAM: transforms.json (top-level fl_x fl_y cx cy
w h, frames[] with file_path, depth_path, transform_matrix = 4x4 c2w in ARKit/OpenGL camera axes),
rgb/<i>.png, depth/<i>.png (uint16, metres * 65535 / 10).

Depth scale: metres = value * integer_depth_scale when the JSON gives it, else value * 10 / 65535.
Intrinsics: top level, else the first frame's copy. Poses are converted to OpenCV camera axes.
Timestamps: frames[i].timestamp when present, else i / 30 s.
"""

from __future__ import annotations

import json

import numpy as np

from ..camera import c2w_opengl_to_opencv
from ..errors import InputError
from .common import IndexedCapture, check_pose, make_intrinsics, sort_by_time
from .images import decode_depth_image, read_bytes, read_color, read_depth_png

DEFAULT_METRES_PER_UNIT = 10.0 / 65535.0


class NeRFCaptureCapture(IndexedCapture):
    format_name = "nerfcapture"

    def __init__(self, path, **options):
        super().__init__(path, **options)
        root = self.path
        jpath = root / "transforms.json"
        try:
            meta = json.loads(read_bytes(jpath))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise InputError(f"{jpath}: not valid JSON ({e})") from None
        frames = meta.get("frames") if isinstance(meta, dict) else None
        if not isinstance(frames, list) or not frames:
            raise InputError(f"{jpath}: needs a non-empty 'frames' list")
        scale = meta.get("integer_depth_scale", DEFAULT_METRES_PER_UNIT)
        try:
            self.metres_per_unit = float(scale)
            assert self.metres_per_unit > 0
        except (TypeError, ValueError, AssertionError):
            raise InputError(f"{jpath}: integer_depth_scale must be a positive number, got {scale!r}") from None

        src = meta if "fl_x" in meta else frames[0]
        try:
            self._color_intr = make_intrinsics(src["fl_x"], src["fl_y"], src["cx"], src["cy"], src["w"], src["h"],
                                               str(jpath))
        except KeyError as e:
            raise InputError(f"{jpath}: missing {e.args[0]} (needs fl_x fl_y cx cy w h)") from None

        self._rgb, self._depth, c2w, stamps = [], [], [], []
        no_depth = 0
        for i, f in enumerate(frames):
            if "file_path" not in f or "transform_matrix" not in f:
                raise InputError(f"{jpath}: frame {i} needs file_path and transform_matrix")
            rgb = self._resolve(f["file_path"])
            dep = self._resolve(f["depth_path"]) if f.get("depth_path") else None
            if dep is None or not dep.is_file():
                no_depth += 1
                continue
            T = check_pose(np.asarray(f["transform_matrix"], dtype=np.float64), f"{jpath} (frame {i})")
            self._rgb.append(rgb)
            self._depth.append(dep)
            c2w.append(None if T is None else c2w_opengl_to_opencv(T))
            stamps.append(float(f.get("timestamp", i / 30.0)))
        if no_depth:
            self.warn(f"{no_depth} of {len(frames)} frames have no depth image (skipped)")
        stamps = np.asarray(stamps)
        order = sort_by_time(stamps, str(jpath), self.warnings)
        self._rgb = [self._rgb[k] for k in order]
        self._depth = [self._depth[k] for k in order]
        c2w = [c2w[k] for k in order]
        if self._depth:
            dh, dw = decode_depth_image(read_bytes(self._depth[0]), str(self._depth[0])).shape[:2]
            if (dw, dh) != self.color_size:
                self._depth_size = (dw, dh)
        self._finish(stamps[order], c2w, f"no frame in {jpath} has a depth image")

    def _resolve(self, rel: str):
        p = self.path / rel
        if p.suffix == "":
            for ext in (".png", ".jpg", ".jpeg"):
                if p.with_suffix(ext).is_file():
                    return p.with_suffix(ext)
        return p

    def _name(self, i, kind):
        return str(self._rgb[i] if kind == "color" else self._depth[i])

    def _read_color(self, i):
        return read_color(self._rgb[i])

    def _read_depth(self, i):
        return read_depth_png(self._depth[i], 1.0 / self.metres_per_unit)
