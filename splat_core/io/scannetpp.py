"""ScanNet++ DSLR (undistorted): dslr/nerfstudio/transforms_undistorted.json (PINHOLE fl_x fl_y cx
cy w h, `frames` and `test_frames`, each with file_path, transform_matrix = 4x4 c2w in OpenGL
camera axes, is_bad), dslr/undistorted_images/<file_path>, and depth rendered from the mesh as
uint16 millimetres (0 invalid), from one of two routes (docs/formats.md, capture layouts section 5):

- SplaTAM's fork of the toolkit (Nik-V9/scannetpp): dslr/undistorted_depths/<stem>.png, already
  undistorted like the colour images (read as is);
- the official toolkit: `common/render.py` (render_dslr: True) writes dslr/render_depth/<stem>.png
  in the fisheye (OPENCV_FISHEYE) camera of dslr/nerfstudio/transforms.json; this reader
  undistorts it to the pinhole camera of transforms_undistorted.json with nearest-neighbour
  sampling (depth is never blended; outside the fisheye image is 0), as the fork does.

`split`: "all" (default: train and test frames together in capture order, i.e. by file name),
"train" or "test". Frames marked is_bad are skipped (counted) unless include_bad=True.
Poses are converted to OpenCV camera axes. Timestamps: position in the sequence (none published).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..camera import Intrinsics, c2w_opengl_to_opencv
from ..errors import InputError
from .camera_files import check_pose, make_intrinsics
from .common import IndexedCapture
from .images import decode_depth_image, raw_depth_to_metres, read_bytes, read_color, read_depth_png

TRANSFORMS = Path("nerfstudio") / "transforms_undistorted.json"
FISHEYE_TRANSFORMS = Path("nerfstudio") / "transforms.json"
DEPTH_SCALE = 1000.0


def find_dslr_dir(path: Path) -> Path | None:
    for cand in (path / "dslr", path):
        if (cand / TRANSFORMS).is_file():
            return cand
    return None


class ScanNetPPCapture(IndexedCapture):
    format_name = "scannetpp"
    registered_by = "ScanNet++: depth rendered from the scan at the DSLR camera"

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
        fisheye = not depths.is_dir() and (dslr / "render_depth").is_dir()
        if fisheye:
            depths = dslr / "render_depth"
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
        if not self._depth and not depths.is_dir():
            raise InputError(f"{dslr}: no depth: expected undistorted_depths/ (SplaTAM's toolkit fork) or "
                             f"render_depth/ (official toolkit, common/render.py with render_dslr: True)")
        try:
            self._color_intr = make_intrinsics(meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"], meta["w"],
                                               meta["h"], str(jpath))
        except KeyError as e:
            raise InputError(f"{jpath}: missing {e.args[0]} (needs fl_x fl_y cx cy w h)") from None
        self._fisheye = FisheyeUndistortion(dslr / FISHEYE_TRANSFORMS, self._color_intr) if fisheye else None
        if self._depth and not fisheye:  # undistorted fisheye depth has the colour size
            dh, dw = decode_depth_image(read_bytes(self._depth[0]), str(self._depth[0])).shape[:2]
            if (dw, dh) != self.color_size:
                self._depth_size = (dw, dh)
        self._finish(np.arange(len(c2w), dtype=np.float64), c2w, f"no frames with depth listed in {jpath}")

    def _name(self, i, kind):
        return str(self._rgb[i] if kind == "color" else self._depth[i])

    def _read_color(self, i):
        return read_color(self._rgb[i])

    def _read_depth(self, i):
        if self._fisheye is None:
            return read_depth_png(self._depth[i], DEPTH_SCALE)
        raw = decode_depth_image(read_bytes(self._depth[i]), str(self._depth[i]))
        return raw_depth_to_metres(self._fisheye.apply(raw, str(self._depth[i])), DEPTH_SCALE, str(self._depth[i]))


class FisheyeUndistortion:
    """Nearest-neighbour resampling of fisheye images (transforms.json: OPENCV_FISHEYE fl_x fl_y cx cy
    k1..k4 w h) onto the pinhole camera of transforms_undistorted.json, as the toolkits map colour."""

    def __init__(self, fisheye_json: Path, pinhole: Intrinsics):
        if not fisheye_json.is_file():
            raise InputError(f"{fisheye_json}: not found; needed to undistort render_depth/ (its fisheye camera)")
        try:
            src = json.loads(read_bytes(fisheye_json))
            K = np.array([[src["fl_x"], 0, src["cx"]], [0, src["fl_y"], src["cy"]], [0, 0, 1]], dtype=np.float64)
            D = np.array([src[k] for k in ("k1", "k2", "k3", "k4")], dtype=np.float64)
            self.size = (int(src["w"]), int(src["h"]))
        except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError) as e:
            raise InputError(f"{fisheye_json}: needed to undistort render_depth/: fl_x fl_y cx cy k1 k2 k3 k4 w h "
                             f"of the fisheye camera ({type(e).__name__}: {e})") from None
        if str(src.get("camera_model", "OPENCV_FISHEYE")) != "OPENCV_FISHEYE":
            raise InputError(f"{fisheye_json}: camera_model {src['camera_model']!r}, expected OPENCV_FISHEYE")
        import cv2

        self._maps = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), pinhole.K, (pinhole.width, pinhole.height),
                                                         cv2.CV_32FC1)

    def apply(self, raw: np.ndarray, name: str) -> np.ndarray:
        import cv2

        if (raw.shape[1], raw.shape[0]) != self.size:
            raise InputError(f"{name}: depth is {raw.shape[1]}x{raw.shape[0]}, expected the fisheye camera's "
                             f"{self.size[0]}x{self.size[1]} (dslr/{FISHEYE_TRANSFORMS.as_posix()})")
        return cv2.remap(raw, *self._maps, interpolation=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=0)
