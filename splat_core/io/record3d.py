"""Record3D: a .r3d file (a zip, read directly) or its unzipped folder.

metadata (JSON): K = 9 numbers column-major for the RGB image (w x h), dw/dh depth size, fps,
poses[i] = [qx, qy, qz, qw, tx, ty, tz] c2w in ARKit/OpenGL camera axes, optional frameTimestamps
and perFrameIntrinsicCoeffs ([fx, fy, cx, cy] per frame at the RGB size; used per frame).
rgbd/<i>.jpg colour; rgbd/<i>.depth LZFSE-compressed float32 metres; rgbd/<i>.conf LZFSE uint8
confidence (0 low, 1 medium, 2 high).

Depth arrays are row-major images in the same orientation as the colour image: a portrait
capture (w < h) stores the 256x192 LiDAR map as 256 rows x 192 columns, and its metadata says
dw=192, dh=256 (docs/formats.md, capture layouts section 1). dw/dh given in the other order are swapped to match the
colour image; files without dw/dh get the depth shape from the decoded size (256x192 LiDAR,
640x480 front camera, or the RGB size), oriented like w/h. Depth and confidence are brought
together with colour to one working resolution (see common.py); depth below `min_confidence` is
masked (default 2, high only, like the public Record3D readers).
"""

from __future__ import annotations

import json
import re

import numpy as np

from ..camera import c2w_opengl_to_opencv, pose_matrix, quat_to_rotmat_np
from ..errors import InputError
from .camera_files import make_intrinsics
from .common import IndexedCapture
from .stores import open_store
from .images import decode_color, sanitize_depth

METADATA_NAMES = ("metadata", "metadata.json")


def _lzfse_decompress(data: bytes, label: str) -> bytes:
    try:
        import lzfse
    except ImportError:
        raise InputError(f"{label}: reading Record3D depth needs the 'lzfse' package (pip install lzfse)") from None
    try:
        return lzfse.decompress(data)
    except Exception as e:  # lzfse.error and friends
        raise InputError(f"{label}: cannot LZFSE-decompress ({e}); corrupt file?") from None


class Record3DCapture(IndexedCapture):
    format_name = "record3d"
    registered_by = "the phone app: ARKit delivers depth registered to the colour image"

    def __init__(self, path, **options):
        super().__init__(path, **options)
        if not self.path.exists():
            raise InputError(f"{self.path}: not found")
        self.store = open_store(self.path)
        meta_name = next((n for n in METADATA_NAMES if self.store.exists(n)), None)
        if meta_name is None:
            raise InputError(f"{self.path}: Record3D capture needs a 'metadata' JSON file and rgbd/")
        mlabel = self.store.label(meta_name)
        try:
            meta = json.loads(self.store.read(meta_name))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise InputError(f"{mlabel}: not valid JSON ({e})") from None
        try:
            K = np.asarray(meta["K"], dtype=np.float64).reshape(3, 3).T  # stored column-major
            w, h = int(meta["w"]), int(meta["h"])
            poses = np.asarray(meta["poses"], dtype=np.float64)
        except (KeyError, ValueError, TypeError) as e:
            raise InputError(f"{mlabel}: needs K (9 numbers), w, h and poses ([qx qy qz qw tx ty tz] per frame) "
                             f"({type(e).__name__}: {e})") from None
        if poses.ndim != 2 or poses.shape[1] != 7:
            raise InputError(f"{mlabel}: poses must be a list of [qx, qy, qz, qw, tx, ty, tz], got shape {poses.shape}")
        self._color_intr = make_intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], w, h, mlabel)

        names = self.store.names()
        jpgs = {int(m.group(1)) for n in names if (m := re.match(r"^rgbd/(\d+)\.jpe?g$", n))}
        n = len(poses)
        if len(jpgs) != n:
            raise InputError(f"{mlabel}: lists {n} poses but rgbd/ holds {len(jpgs)} colour images (counts must match)")
        self._ext = {i: ("jpg" if self.store.exists(f"rgbd/{i}.jpg") else "jpeg") for i in range(n)}
        keep = [i for i in range(n) if self.store.exists(f"rgbd/{i}.depth")]
        if len(keep) < n:
            self.warn(f"{n - len(keep)} of {n} frames have no .depth file (skipped)")
        self._ids = keep
        self._has_conf = {i: self.store.exists(f"rgbd/{i}.conf") for i in keep}
        self._depth_shape = self._depth_layout(meta, w, h, mlabel)
        rows, cols = self._depth_shape
        if (cols, rows) != (w, h):
            self._depth_size = (cols, rows)
        self._frame_intr = self._per_frame_intrinsics(meta, n, w, h, mlabel)

        fps = float(meta.get("fps", 30) or 30)
        stamps_all = np.asarray(meta.get("frameTimestamps", []), dtype=np.float64)
        if len(stamps_all) != n:
            stamps_all = np.arange(n) / fps
        stamps = stamps_all[keep]
        if np.any(np.diff(stamps) < 0):
            raise InputError(f"{mlabel}: frameTimestamps are not in order; frames are paired with poses by index, "
                             f"so this capture cannot be read safely")
        c2w = []
        for i in keep:
            qx, qy, qz, qw, tx, ty, tz = poses[i]
            q = np.array([qw, qx, qy, qz])
            if not np.all(np.isfinite(poses[i])) or np.linalg.norm(q) < 1e-6:
                c2w.append(None)
                continue
            c2w.append(c2w_opengl_to_opencv(pose_matrix(quat_to_rotmat_np(q / np.linalg.norm(q)), [tx, ty, tz])))
        self._finish(stamps, c2w, f"no frame in {self.path} has depth")

    def _depth_layout(self, meta, w, h, mlabel) -> tuple[int, int]:
        """(rows, cols) of the depth arrays, in the colour image's orientation."""
        if "dw" in meta and "dh" in meta:
            try:
                dims = sorted([int(meta["dw"]), int(meta["dh"])])
            except (TypeError, ValueError):
                raise InputError(f"{mlabel}: dw and dh must be integers, got {meta['dw']!r}, {meta['dh']!r}") from None
            short, long = dims
        elif not self._ids:
            return h, w
        else:  # older files: the decoded size tells (LiDAR, front camera, or depth at the RGB size)
            n = self._decode_raw(0, "depth", np.float32).size
            sizes = [(256, 192), (640, 480), (max(w, h), min(w, h))]
            match = next((s for s in sizes if s[0] * s[1] == n), None)
            if match is None:
                raise InputError(f"{self._name(0, 'depth')}: decoded {n} values; without dw/dh in the metadata "
                                 f"expected 256x192 (LiDAR), 640x480 (front camera) or {w}x{h} (the RGB size)")
            long, short = match
        return (long, short) if h > w else (short, long)

    def _per_frame_intrinsics(self, meta, n, w, h, mlabel):
        coeffs = meta.get("perFrameIntrinsicCoeffs")
        if not coeffs:
            return None
        try:
            c = np.asarray(coeffs, dtype=np.float64)
        except (TypeError, ValueError):
            c = None
        if c is None or c.shape != (n, 4):
            self.warn(f"{mlabel}: perFrameIntrinsicCoeffs is not one [fx, fy, cx, cy] per pose; "
                      f"using K for every frame")
            return None
        return {i: make_intrinsics(*c[i], w, h, f"{mlabel} (perFrameIntrinsicCoeffs[{i}])") for i in self._ids}

    def _frame_color_intr(self, i):
        return self._color_intr if self._frame_intr is None else self._frame_intr[self._ids[i]]

    def _name(self, i, kind):
        ext = {"color": self._ext[self._ids[i]], "depth": "depth", "confidence": "conf"}[kind]
        return self.store.label(f"rgbd/{self._ids[i]}.{ext}")

    def _read_color(self, i):
        return decode_color(self.store.read(f"rgbd/{self._ids[i]}.{self._ext[self._ids[i]]}"), self._name(i, "color"))

    def _decode_raw(self, i, kind, dtype):
        label = self._name(i, kind)
        raw = _lzfse_decompress(self.store.read(f"rgbd/{self._ids[i]}.{'depth' if kind == 'depth' else 'conf'}"), label)
        if len(raw) % np.dtype(dtype).itemsize:
            raise InputError(f"{label}: decoded {len(raw)} bytes, not a whole number of {np.dtype(dtype).name} values")
        return np.frombuffer(raw, dtype=dtype)

    def _decode(self, i, kind, dtype):
        arr = self._decode_raw(i, kind, dtype)
        rows, cols = self._depth_shape
        if arr.size != rows * cols:
            raise InputError(f"{self._name(i, kind)}: decoded {arr.size} values, expected {rows}x{cols} = "
                             f"{rows * cols} (dw/dh in the metadata, else the first frame's size)")
        return arr.reshape(rows, cols)

    def _read_depth(self, i):
        return sanitize_depth(self._decode(i, "depth", np.float32), self._name(i, "depth"))

    def _read_confidence(self, i):
        if not self._has_conf[self._ids[i]]:
            return None
        return self._decode(i, "confidence", np.uint8)
