"""ScanNet++ DSLR (undistorted): dslr/nerfstudio/transforms_undistorted.json (fl_x fl_y cx cy w h,
`frames` and `test_frames`, each with file_path, transform_matrix = 4x4 c2w in OpenGL camera
axes, is_bad), dslr/undistorted_images/<file_path>, dslr/undistorted_depths/<stem>.png (uint16 mm,
rendered from the mesh).

`split`: "all" (default: train and test frames together in capture order, i.e. by file name),
"train" or "test". Frames marked is_bad are skipped (counted) unless include_bad=True.
Poses are converted to OpenCV camera axes. Timestamps: position in the sequence (none published).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..camera import c2w_opengl_to_opencv
from ..errors import InputError
from .common import IndexedCapture, check_pose, make_intrinsics
from .images import decode_depth_image, read_bytes, read_color, read_depth_png

TRANSFORMS = Path("nerfstudio") / "transforms_undistorted.json"
DEPTH_SCALE = 1000.0


def find_dslr_dir(path: Path) -> Path | None:
    for cand in (path / "dslr", path):
        if (cand / TRANSFORMS).is_file():
            return cand
    return None


class ScanNetPPCapture(IndexedCapture):
    format_name = "scannetpp"

    def __init__(self, path, *, split: str = "all", include_bad: bool = False, **options):
        super().__init__(path, **options)
        dslr = find_dslr_dir(self.path)
        if dslr is None:
            raise InputError(f"{self.path}: ScanNet++ layout needs dslr/{TRANSFORMS.as_posix()}")
        if split not in ("all", "train", "test"):
            raise InputError(f"split must be all, train or test, got {split!r}")
        jpath = dslr / TRANSFORMS
        try:
            meta = json.loads(read_bytes(jpath))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise InputError(f"{jpath}: not valid JSON ({e})") from None
        if not isinstance(meta, dict):
            raise InputError(f"{jpath}: expected a JSON object")
        entries = []
        if split in ("all", "train"):
            entries += list(meta.get("frames", []))
        if split in ("all", "test"):
            entries += list(meta.get("test_frames", []))
        try:
            entries.sort(key=lambda f: str(f["file_path"]))
        except (KeyError, TypeError):
            raise InputError(f"{jpath}: every frame needs file_path and transform_matrix") from None
        n_bad = sum(bool(f.get("is_bad", False)) for f in entries)
        if n_bad and not include_bad:
            entries = [f for f in entries if not f.get("is_bad", False)]
            self.warn(f"{n_bad} frames marked is_bad skipped")
        images, depths = dslr / "undistorted_images", dslr / "undistorted_depths"
        self._rgb, self._depth, c2w = [], [], []
        no_depth = 0
        for f in entries:
            rgb = images / f["file_path"]
            dep = depths / (Path(f["file_path"]).stem + ".png")
            if not dep.is_file():
                no_depth += 1
                continue
            self._rgb.append(rgb)
            self._depth.append(dep)
            T = check_pose(np.asarray(f["transform_matrix"], dtype=np.float64), f"{jpath} ({f['file_path']})")
            c2w.append(None if T is None else c2w_opengl_to_opencv(T))
        if no_depth:
            self.warn(f"{no_depth} frames have no depth in {depths} (skipped)")
        try:
            self._color_intr = make_intrinsics(meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"], meta["w"],
                                               meta["h"], str(jpath))
        except KeyError as e:
            raise InputError(f"{jpath}: missing {e.args[0]} (needs fl_x fl_y cx cy w h)") from None
        if self._depth:
            dh, dw = decode_depth_image(read_bytes(self._depth[0]), str(self._depth[0])).shape[:2]
            if (dw, dh) != self.color_size:
                self._depth_size = (dw, dh)
        self._finish(np.arange(len(c2w), dtype=np.float64), c2w, f"no frames with depth listed in {jpath}")

    def _name(self, i, kind):
        return str(self._rgb[i] if kind == "color" else self._depth[i])

    def _read_color(self, i):
        return read_color(self._rgb[i])

    def _read_depth(self, i):
        return read_depth_png(self._depth[i], DEPTH_SCALE)
