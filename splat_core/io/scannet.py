"""ScanNet (v1/v2, as exported by its SensReader): color/<n>.jpg (1296x968), depth/<n>.png
(640x480 uint16 millimetres), pose/<n>.txt (4x4 c2w, OpenCV axes; -inf rows mark frames without a
pose), intrinsic/intrinsic_color.txt (4x4 K of the colour sensor) and intrinsic_depth.txt.

SensorData.py writes the intrinsics of the sensor's own resolution even when it exports images
resized (`image_size`): K is scaled from the size it was written for (1296x968 colour, 640x480
depth, told apart from the image's size by the principal point) to the images found, with a
warning. Frames pair by their number. By default colour is brought down to the depth resolution
with the colour intrinsics scaled (`resolution="color"` enlarges depth instead). Without an
intrinsic/ folder or camera file, the typical ScanNet colour camera (1169.62 1167.11 646.30 489.93
at 1296x968) is assumed, with a warning. Timestamps: frame number / 30 s.
"""

from __future__ import annotations

import re

import numpy as np

from ..errors import InputError
from .camera_files import check_pose, find_camera_file, intrinsics_for_image, load_camera_file, make_intrinsics
from .common import IndexedCapture
from .images import decode_depth_image, read_bytes, read_color, read_depth_png

DEPTH_SCALE = 1000.0
TYPICAL_COLOR_K = dict(fx=1169.62, fy=1167.11, cx=646.30, cy=489.93, width=1296, height=968)
SENSOR_COLOR_SIZE, SENSOR_DEPTH_SIZE = (1296, 968), (640, 480)
FPS = 30.0


def _numbered(folder, exts) -> dict[int, object]:
    out = {}
    if folder.is_dir():
        for p in folder.iterdir():
            m = re.match(r"^(?:frame-)?(\d+)(?:\.color|\.depth|\.pose)?\.(\w+)$", p.name)
            if m and m.group(2).lower() in exts:
                out[int(m.group(1))] = p
    return out


def _read_matrix(path, shape=(4, 4)) -> np.ndarray:
    text = read_bytes(path).decode(errors="replace")
    try:
        vals = [float(v) for v in text.replace(",", " ").split()]
    except ValueError:
        raise InputError(f"{path}: expected {shape[0]}x{shape[1]} numbers") from None
    if len(vals) != shape[0] * shape[1]:
        raise InputError(f"{path}: expected {shape[0] * shape[1]} numbers ({shape[0]}x{shape[1]}), got {len(vals)}")
    return np.asarray(vals).reshape(shape)


class ScanNetCapture(IndexedCapture):
    format_name = "scannet"
    registered_by = "ScanNet's SensReader export: its frames are aligned (its extrinsic_depth must not be applied)"

    def __init__(self, path, *, depth_scale: float = DEPTH_SCALE, **options):
        super().__init__(path, **options)
        root = self.path
        colors = _numbered(root / "color", {"jpg", "jpeg", "png"})
        depths = _numbered(root / "depth", {"png"})
        poses = _numbered(root / "pose", {"txt"})
        if not colors or not depths:
            raise InputError(f"{root}: ScanNet layout needs color/<n>.jpg, depth/<n>.png and pose/<n>.txt")
        ids = sorted(colors)
        keep = [i for i in ids if i in depths]
        if len(keep) < len(ids):
            self.warn(f"{len(ids) - len(keep)} of {len(ids)} colour frames have no depth image (skipped)")
        if not keep:
            raise InputError(f"{root}: no frame number has both color/ and depth/ images")
        self._rgb = [colors[i] for i in keep]
        self._depth = [depths[i] for i in keep]
        self.depth_scale = float(depth_scale)

        first = read_color(self._rgb[0])
        cw, ch = first.shape[1], first.shape[0]
        dh, dw = decode_depth_image(read_bytes(self._depth[0]), str(self._depth[0])).shape[:2]
        kc, kd = root / "intrinsic" / "intrinsic_color.txt", root / "intrinsic" / "intrinsic_depth.txt"
        cam_file = find_camera_file(root)
        if kc.is_file():
            self._color_intr = self._sensor_intrinsics(kc, cw, ch, SENSOR_COLOR_SIZE)
        elif kd.is_file():
            self._color_intr = self._sensor_intrinsics(kd, dw, dh, SENSOR_DEPTH_SIZE).scaled(cw, ch)
        elif cam_file:
            cam = load_camera_file(cam_file)
            intr = make_intrinsics(cam["fx"], cam["fy"], cam["cx"], cam["cy"], cam.get("width", cw),
                                   cam.get("height", ch), str(cam_file))
            self._color_intr = intr if (intr.width, intr.height) == (cw, ch) else intr.scaled(cw, ch)
        else:
            t = TYPICAL_COLOR_K
            self._color_intr = make_intrinsics(t["fx"], t["fy"], t["cx"], t["cy"], t["width"], t["height"],
                                               str(root)).scaled(cw, ch)
            self.warn("no intrinsic/intrinsic_color.txt: assuming the typical ScanNet colour camera")
        if (dw, dh) != (cw, ch):
            self._depth_size = (dw, dh)

        c2w = []
        for i in keep:
            c2w.append(check_pose(_read_matrix(poses[i]), str(poses[i])) if i in poses else None)
        n_inf = sum(1 for i in keep if i in poses) - sum(T is not None for T in c2w)
        if n_inf:
            self.warn(f"{n_inf} frames have an invalid (-inf) pose in pose/")
        self._finish(np.asarray(keep, dtype=np.float64) / FPS, c2w, f"no frames in {root}")

    def _sensor_intrinsics(self, path, width, height, sensor_size):
        K = _read_matrix(path)
        intr, written_for = intrinsics_for_image(K[0, 0], K[1, 1], K[0, 2], K[1, 2], width, height, str(path),
                                                 [sensor_size])
        if written_for:
            self.warn(f"{path.name} is for {written_for[0]}x{written_for[1]} images; scaled to the {width}x{height} "
                      f"images exported")
        return intr

    def _name(self, i, kind):
        return str(self._rgb[i] if kind == "color" else self._depth[i])

    def _read_color(self, i):
        return read_color(self._rgb[i])

    def _read_depth(self, i):
        return read_depth_png(self._depth[i], self.depth_scale)
