"""NeRFCapture (iPhone app streaming over the network), as the capture scripts save it
(docs/formats.md, capture layouts section 3), in a folder or a zip of one:

- SplaTAM's `scripts/nerfcapture2dataset.py`: rgb/<i>.png, depth/<i>.png;
- instant-ngp's `scripts/nerfcapture2nerf.py`: images/<i>.png, images/<i>.depth.png, with
  file_path written without extension ("images/<i>").

Both write transforms.json with top-level fl_x fl_y cx cy w h (the first frame's),
integer_depth_scale (metres per unit: depth_scale / 65535, depth_scale 10 by default), and frames
with file_path, depth_path, transform_matrix (row-major 4x4 c2w, ARKit/OpenGL camera axes,
converted to OpenCV here) and the frame's own fl_x fl_y cx cy w h (used per frame). Depth is
uint16, already nearest-upsampled to the RGB size. Neither script writes timestamps: frames are
i / 30 s apart unless frames[i].timestamp is given.

The app's own offline export (images/<i>.png, images/<i>.depth.png, key `depth_integer_scale`)
is refused: its depth images are 8-bit RGBA pictures at screen scale, or absent (NeRFCapture
issues #10 and #17, SplaTAM #7 and #59).
"""

from __future__ import annotations

import json
import posixpath

import numpy as np

from ..camera import c2w_opengl_to_opencv
from ..errors import InputError
from .camera_files import check_pose, make_intrinsics
from .common import IndexedCapture, sort_by_time
from .stores import open_store
from .images import decode_color, decode_depth_image, raw_depth_to_metres

DEFAULT_METRES_PER_UNIT = 10.0 / 65535.0
STREAMING_HINT = "record over the network instead: `splatam capture nerfcapture --out DIR` with the app in online mode"
PNG_COLOUR_TYPES = {0: "grey", 2: "RGB", 3: "palette", 4: "grey+alpha", 6: "RGBA"}


def _png_kind(data: bytes) -> str:
    """'8-bit RGBA 5760x4320' from a PNG header, without decoding the image."""
    if len(data) < 26 or not data.startswith(b"\x89PNG"):
        return "not a PNG"
    w, h = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    return f"{data[24]}-bit {PNG_COLOUR_TYPES.get(data[25], '?')} {w}x{h}"


class NeRFCaptureCapture(IndexedCapture):
    format_name = "nerfcapture"
    registered_by = "the phone app: ARKit delivers depth registered to the colour image"

    def __init__(self, path, **options):
        super().__init__(path, **options)
        if not self.path.exists():
            raise InputError(f"{self.path}: not found")
        self.store = open_store(self.path)
        jlabel = self.store.label("transforms.json")
        if not self.store.exists("transforms.json"):
            raise InputError(f"{self.path}: a NeRFCapture capture needs transforms.json")
        try:
            meta = json.loads(self.store.read("transforms.json"))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise InputError(f"{jlabel}: not valid JSON ({e})") from None
        frames = meta.get("frames") if isinstance(meta, dict) else None
        if not isinstance(frames, list) or not frames or not all(isinstance(f, dict) for f in frames):
            raise InputError(f"{jlabel}: needs a non-empty 'frames' list of objects")
        if "depth_integer_scale" in meta and "integer_depth_scale" not in meta:
            self._refuse_offline_export(jlabel, frames)
        scale = meta.get("integer_depth_scale", DEFAULT_METRES_PER_UNIT)
        try:
            self.metres_per_unit = float(scale)
            assert self.metres_per_unit > 0
        except (TypeError, ValueError, AssertionError):
            raise InputError(f"{jlabel}: integer_depth_scale must be a positive number, got {scale!r}") from None
        self._color_intr = self._intrinsics(meta if "fl_x" in meta else frames[0], jlabel)

        self._rgb, self._depth, self._intr, c2w, stamps = [], [], [], [], []
        no_depth = 0
        for i, f in enumerate(frames):
            if "file_path" not in f or "transform_matrix" not in f:
                raise InputError(f"{jlabel}: frame {i} needs file_path and transform_matrix")
            dep = self._resolve(f["depth_path"]) if f.get("depth_path") else None
            if dep is None or not self.store.exists(dep):
                no_depth += 1
                continue
            T = check_pose(np.asarray(f["transform_matrix"], dtype=np.float64), f"{jlabel} (frame {i})")
            self._rgb.append(self._resolve(f["file_path"]))
            self._depth.append(dep)
            self._intr.append(self._intrinsics(f, f"{jlabel} (frame {i})") if "fl_x" in f else self._color_intr)
            c2w.append(None if T is None else c2w_opengl_to_opencv(T))
            stamps.append(float(f.get("timestamp", i / 30.0)))
        if no_depth:
            self.warn(f"{no_depth} of {len(frames)} frames have no depth image (skipped)")
        stamps = np.asarray(stamps)
        order = sort_by_time(stamps, jlabel, self.warnings)
        self._rgb, self._depth, self._intr = ([v[k] for k in order] for v in (self._rgb, self._depth, self._intr))
        if self._depth:
            dh, dw = self._read_raw_depth(0).shape[:2]
            if (dw, dh) != self.color_size:
                self._depth_size = (dw, dh)
        self._finish(stamps[order], [c2w[k] for k in order], f"no frame in {jlabel} has a depth image")

    def _refuse_offline_export(self, jlabel, frames):
        dep = next((self._resolve(f["depth_path"]) for f in frames if f.get("depth_path")), None)
        found = "no depth images" if dep is None or not self.store.exists(dep) else \
            f"depth images like {dep} are {_png_kind(self.store.read(dep))}"
        raise InputError(f"{jlabel}: this is the NeRFCapture app's offline export, whose depth cannot be used "
                         f"({found}; broken upstream: NeRFCapture #10, #17, SplaTAM #59); {STREAMING_HINT}")

    @staticmethod
    def _intrinsics(src: dict, where: str):
        try:
            return make_intrinsics(src["fl_x"], src["fl_y"], src["cx"], src["cy"], src["w"], src["h"], where)
        except KeyError as e:
            raise InputError(f"{where}: missing {e.args[0]} (needs fl_x fl_y cx cy w h)") from None

    def _resolve(self, rel) -> str:
        rel = posixpath.normpath(str(rel))
        if posixpath.splitext(rel)[1] == "":
            for ext in (".png", ".jpg", ".jpeg"):
                if self.store.exists(rel + ext):
                    return rel + ext
        return rel

    def _frame_color_intr(self, i):
        return self._intr[i]

    def _name(self, i, kind):
        return self.store.label(self._rgb[i] if kind == "color" else self._depth[i])

    def _read_color(self, i):
        return decode_color(self.store.read(self._rgb[i]), self._name(i, "color"))

    def _read_raw_depth(self, i):
        return decode_depth_image(self.store.read(self._depth[i]), self._name(i, "depth"))

    def _read_depth(self, i):
        return raw_depth_to_metres(self._read_raw_depth(i), 1.0 / self.metres_per_unit, self._name(i, "depth"))
