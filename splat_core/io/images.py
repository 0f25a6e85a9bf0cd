"""Reading colour and depth images with errors that name the file.

Every reader goes through these helpers so that the conventions hold everywhere:
colour is float32 HxWx3 RGB in [0, 1]; depth is float32 HxW metres with 0 = invalid
(NaN, inf, negative and sensor "no reading" values such as 65535 all become 0, and are counted).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError


def _cv2():
    import cv2

    return cv2


def decode_color(data: bytes, name: str) -> np.ndarray:
    """Encoded image bytes (png/jpg/...) -> HxWx3 float32 RGB in [0, 1]."""
    cv2 = _cv2()
    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED) if data else None
    if img is None:
        raise InputError(f"{name}: cannot decode colour image (missing, empty or corrupt file)")
    return color_to_float(img, name, bgr=True)


def color_to_float(img: np.ndarray, name: str, bgr: bool) -> np.ndarray:
    """uint8/uint16/float image (gray, 3 or 4 channels) -> HxWx3 float32 RGB in [0, 1]."""
    cv2 = _cv2()
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"{name}: expected a colour image, got an array of shape {img.shape}")
    if bgr:
        img = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2RGB)
    if img.dtype == np.uint8:
        out = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        out = img.astype(np.float32) / 65535.0
    else:
        out = np.clip(img.astype(np.float32), 0.0, 1.0)
    return out


def read_bytes(path: Path) -> bytes:
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None


def read_color(path: Path) -> np.ndarray:
    return decode_color(read_bytes(path), str(path))


def decode_depth_image(data: bytes, name: str) -> np.ndarray:
    """Encoded single-channel depth image (normally 16-bit PNG) -> raw integer/float array."""
    cv2 = _cv2()
    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED) if data else None
    if img is None:
        raise InputError(f"{name}: cannot decode depth image (missing, empty or corrupt file)")
    if img.ndim == 3:
        if img.shape[2] == 1 or np.all(img[..., :1] == img):
            img = img[..., 0]
        else:
            raise InputError(f"{name}: expected a single-channel depth image, got {img.shape[2]} channels")
    if img.dtype == np.uint8:
        raise InputError(f"{name}: expected a 16-bit depth image, got 8-bit (depth saved as an ordinary picture?)")
    return img


def raw_depth_to_metres(raw: np.ndarray, units_per_metre: float, name: str,
                        invalid_values: tuple = (65535,)) -> tuple[np.ndarray, int]:
    """Integer depth -> float32 metres (0 invalid). Returns (depth, number of pixels invalidated)."""
    bad = np.zeros(raw.shape, dtype=bool)
    if np.issubdtype(raw.dtype, np.integer):
        for v in invalid_values:
            bad |= raw == v
    depth = raw.astype(np.float32) / np.float32(units_per_metre)
    depth, n_bad = sanitize_depth(depth, name)
    depth[bad] = 0.0
    return depth, n_bad + int(bad.sum())


def sanitize_depth(depth: np.ndarray, name: str = "") -> tuple[np.ndarray, int]:
    """NaN / inf / negative -> 0 (invalid). Returns (float32 depth, number of pixels invalidated)."""
    depth = np.asarray(depth, dtype=np.float32)
    if depth.ndim != 2:
        raise InputError(f"{name}: expected an HxW depth map, got shape {depth.shape}")
    bad = ~np.isfinite(depth) | (depth < 0)
    n_bad = int(bad.sum())
    if n_bad:
        depth = depth.copy()
        depth[bad] = 0.0
    return depth, n_bad


def read_depth_png(path: Path, units_per_metre: float, invalid_values: tuple = (65535,)) -> tuple[np.ndarray, int]:
    raw = decode_depth_image(read_bytes(path), str(path))
    return raw_depth_to_metres(raw, units_per_metre, str(path), invalid_values)


def write_color_png(path: Path, color: np.ndarray) -> None:
    cv2 = _cv2()
    img = np.clip(np.round(np.asarray(color) * 255.0), 0, 255).astype(np.uint8)
    if not cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
        raise InputError(f"{path}: cannot write image")


def depth_to_units(depth_m: np.ndarray, units_per_metre: float) -> tuple[np.ndarray, int]:
    """Metres -> uint16 units for a 16-bit PNG. NaN/inf/negative become 0 (invalid), and so does
    depth beyond the 16-bit range; returns (units, how many were beyond the range)."""
    d = np.nan_to_num(np.asarray(depth_m, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    raw = np.round(d * units_per_metre)
    over = raw > 65534  # 65535 is read back as "no reading"
    raw[over | (raw < 0)] = 0
    return raw.astype(np.uint16), int(over.sum())


def write_depth_png(path: Path, depth_m: np.ndarray, units_per_metre: float) -> int:
    """Metres -> 16-bit PNG. Depth beyond the 16-bit range becomes 0 (invalid); returns how many."""
    raw, n_over = depth_to_units(depth_m, units_per_metre)
    if not _cv2().imwrite(str(path), raw):
        raise InputError(f"{path}: cannot write depth image")
    return n_over


def encode_png(image: np.ndarray, name: str) -> bytes:
    """HxWx3 uint8 RGB or HxW uint16 -> PNG bytes (for writing with io.atomic)."""
    cv2 = _cv2()
    img = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise InputError(f"{name}: cannot encode PNG")
    return buf.tobytes()
