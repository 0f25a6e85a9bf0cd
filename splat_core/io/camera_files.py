"""Camera files beside a capture (camera.yaml / camera.json / cam_params.json), intrinsics checked
against the images, and reference poses checked for finiteness."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from ..camera import Intrinsics
from ..errors import InputError
from ..registration import parse_two_cameras


CAMERA_FILES = ("camera.yaml", "camera.yml", "camera.json", "cam_params.json")


def find_camera_file(folder: Path) -> Path | None:
    for name in CAMERA_FILES:
        if (Path(folder) / name).is_file():
            return Path(folder) / name
    return None


def load_camera_file(path: Path) -> dict:
    """camera.yaml / camera.json (fx fy cx cy width height [depth_scale] [depth_registered_to_rgb]
    [color_intrinsics depth_to_color]) or NICE-SLAM's cam_params.json ({"camera": {w h fx fy cx cy
    scale}}) -> dict with those keys as floats, "registered" (bool) when the file says whether depth
    is registered to colour, and "two_cameras" (registration.TwoCameras) when it describes the colour
    camera beside the depth camera (fx fy cx cy width height are then the depth camera's)."""
    path = Path(path)
    text = path.read_text(errors="replace")
    try:
        if path.suffix == ".json":
            data = json.loads(text)
        else:
            import yaml

            data = yaml.safe_load(io.StringIO(text))
    except Exception as e:  # yaml and json raise many types
        raise InputError(f"{path}: cannot parse ({str(e).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a mapping with fx fy cx cy width height")
    if isinstance(data.get("camera"), dict):
        data = data["camera"]
    if isinstance(data.get("camera_params"), dict):  # SplaTAM-style data yaml
        data = data["camera_params"]
    aliases = {"width": ("width", "w", "image_width"), "height": ("height", "h", "image_height"),
               "fx": ("fx", "fl_x"), "fy": ("fy", "fl_y"), "cx": ("cx",), "cy": ("cy",),
               "depth_scale": ("depth_scale", "scale", "png_depth_scale")}
    out = {}
    for key, names in aliases.items():
        for n in names:
            if n in data:
                try:
                    out[key] = float(data[n])
                except (TypeError, ValueError):
                    raise InputError(f"{path}: '{n}' must be a number, got {data[n]!r}") from None
                break
    missing = [k for k in ("fx", "fy", "cx", "cy") if k not in out]
    if missing:
        raise InputError(f"{path}: missing {', '.join(missing)} (needs fx fy cx cy width height [depth_scale])")
    if "depth_scale" in out and not out["depth_scale"] > 0:
        raise InputError(f"{path}: depth_scale must be positive, got {out['depth_scale']}")
    if "depth_registered_to_rgb" in data:
        if not isinstance(data["depth_registered_to_rgb"], bool):
            raise InputError(f"{path}: 'depth_registered_to_rgb' must be true or false, "
                             f"got {data['depth_registered_to_rgb']!r}")
        out["registered"] = data["depth_registered_to_rgb"]
    two = parse_two_cameras(data, str(path))
    if two is not None:
        if out.get("registered") is True:
            raise InputError(f"{path}: 'depth_registered_to_rgb: true' contradicts color_intrinsics / "
                             f"depth_to_color (a registered capture has one camera)")
        out["two_cameras"] = two
    return out


def make_intrinsics(fx, fy, cx, cy, width, height, where: str) -> Intrinsics:
    """Intrinsics, with any complaint prefixed by the file it came from."""
    try:
        return Intrinsics(float(fx), float(fy), float(cx), float(cy), int(round(float(width))),
                          int(round(float(height))))
    except InputError as e:
        raise InputError(f"{where}: {e}") from None
    except (TypeError, ValueError) as e:
        raise InputError(f"{where}: bad intrinsics ({e})") from None


def intrinsics_for_image(fx, fy, cx, cy, width, height, where: str, sensor_sizes=()):
    """K from a file, applied to the (width x height) images it describes.

    Exports that resize images can keep the intrinsics of the sensor's resolution (ScanNet's
    SensReader with `image_size`; a Stray Scanner video smaller than camera_matrix.csv). A principal
    point more than a quarter of the image away from its centre means K was written for another
    size: the first of `sensor_sizes` centred on it, else twice the principal point. Returns
    (intrinsics at width x height, the size K was written for when it had to be scaled, else None).
    """
    def centred(w, h, tol):
        return abs(2 * (cx + 0.5) / w - 1) <= tol and abs(2 * (cy + 0.5) / h - 1) <= tol

    if width <= 0 or height <= 0 or centred(width, height, 0.25):  # (make_intrinsics refuses a bad size)
        return make_intrinsics(fx, fy, cx, cy, width, height, where), None
    kw, kh = next(((w, h) for w, h in sensor_sizes if centred(w, h, 0.1)),
                  (int(round(2 * cx + 1)), int(round(2 * cy + 1))))
    return make_intrinsics(fx, fy, cx, cy, kw, kh, where).scaled(width, height), (kw, kh)


def image_size(data: bytes, name: str) -> tuple[int, int]:
    """(width, height) of an encoded image."""
    from .images import decode_color

    img = decode_color(data, name)
    return img.shape[1], img.shape[0]


def check_pose(T, where: str) -> np.ndarray | None:
    """A 4x4 c2w from a file, or None when it is marked invalid (non-finite, as ScanNet's -inf)."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise InputError(f"{where}: expected a 4x4 pose, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        return None
    R = T[:3, :3]
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-2 or abs(np.linalg.det(R) - 1) > 1e-2:
        raise InputError(f"{where}: pose rotation is not orthonormal (scaled or corrupt matrix?)")
    return T
