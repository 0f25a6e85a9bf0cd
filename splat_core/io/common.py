"""What the capture readers share: a lazily indexed FrameSource, file access inside folders or
zip archives, camera files (camera.yaml / camera.json / cam_params.json).

Policies every reader follows (stated once here):
- A frame without depth is skipped and counted in `source.warnings`; pairing is never shifted
  to fill the gap.
- A frame without a reference pose (no ground-truth sample near it, or an invalid -inf pose) is
  kept with `c2w_ref = None` and counted: reference poses are for evaluation only.
- Colour and depth of different sizes are brought to one working resolution:
  `resolution="depth"` (default) shrinks colour to the depth size with area averaging,
  `resolution="color"` enlarges depth to the colour size with nearest neighbour. Depth is never
  blended. Intrinsics are scaled with `Intrinsics.scaled`.
- Phone confidence maps (ARKit's 0 low, 1 medium, 2 high): depth with confidence below
  `min_confidence` becomes invalid. Default 2 (high only), as viser's Record3D loader, usa's
  reader, concept-graphs' converter and Stray Scanner's own `convert_to_open3d.py` do for
  reconstruction (docs/formats.md, capture layouts section 1); the map is built from depth, and medium-confidence pixels
  are where flying pixels at depth edges and far range live. StrayVisualizer's point-cloud view
  defaults to 1: pass `min_confidence=1` for that denser, noisier depth, or 0 to keep everything.
- Intrinsics that vary per frame (ARKit refocuses) are given per frame when the capture stores
  them; `intrinsics` is then the capture's nominal camera.
"""

from __future__ import annotations

import io
import json
import threading
import zipfile
import zlib
from pathlib import Path

import numpy as np

from ..camera import Intrinsics
from ..errors import InputError
from ..frame import Frame, resize_to
from .source import FrameSource

RESOLUTIONS = ("depth", "color")
DEFAULT_MIN_CONFIDENCE = 2  # ARKit high confidence only (see above)


# ----------------------------------------------------------------------------- the base reader

class IndexedCapture(FrameSource):
    """A capture whose frames are addressed by index and read from files on demand.

    Subclasses fill, in their constructor: `_timestamps` (seconds, one per frame), `_c2w` (list of
    4x4 c2w OpenCV or None), `_color_intr` (intrinsics of the colour images as stored) and, when
    depth is stored at another size, `_depth_size` (width, height); then implement `_read_color`,
    `_read_depth` and optionally `_read_confidence`.
    """

    format_name = "unknown"

    def __init__(self, path, *, resolution: str = "depth", min_confidence: int | None = None):
        if resolution not in RESOLUTIONS:
            raise InputError(f"resolution must be one of {RESOLUTIONS}, got {resolution!r}")
        self.path = Path(path)
        self.resolution = resolution
        self.min_confidence = DEFAULT_MIN_CONFIDENCE if min_confidence is None else int(min_confidence)
        self.warnings: list[str] = []
        self.invalid_depth_pixels = 0  # NaN / inf / negative / "no reading" pixels seen so far
        self._timestamps = np.zeros(0)
        self._c2w: list[np.ndarray | None] = []
        self._color_intr: Intrinsics | None = None
        self._depth_size: tuple[int, int] | None = None

    # -- to implement
    def _read_color(self, i: int) -> np.ndarray:
        raise NotImplementedError

    def _read_depth(self, i: int) -> tuple[np.ndarray, int]:
        """(HxW float32 metres with 0 invalid, number of pixels invalidated) and the file's name."""
        raise NotImplementedError

    def _read_confidence(self, i: int) -> np.ndarray | None:
        return None

    def _frame_color_intr(self, i: int) -> Intrinsics:
        """Intrinsics of frame i's colour image as stored (override for per-frame intrinsics)."""
        return self._color_intr

    def _name(self, i: int, kind: str) -> str:
        """The file behind frame i's colour/depth, for error messages."""
        return f"{self.path} frame {i} ({kind})"

    # -- FrameSource
    def __len__(self) -> int:
        return len(self._timestamps)

    @property
    def timestamps(self) -> np.ndarray:
        return self._timestamps

    @property
    def color_size(self) -> tuple[int, int]:
        return self._color_intr.width, self._color_intr.height

    @property
    def depth_size(self) -> tuple[int, int]:
        return self._depth_size or self.color_size

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the frames this source yields."""
        return self.depth_size if self.resolution == "depth" else self.color_size

    @property
    def intrinsics(self) -> Intrinsics:
        return self._at_working_size(self._color_intr)

    def _at_working_size(self, intr: Intrinsics) -> Intrinsics:
        w, h = self.size
        return intr if (w, h) == (intr.width, intr.height) else intr.scaled(w, h)

    @property
    def has_reference_poses(self) -> bool:
        return any(T is not None for T in self._c2w)

    def reference_c2w(self) -> np.ndarray | None:
        if not self.has_reference_poses:
            return None
        out = np.full((len(self), 4, 4), np.nan)
        for i, T in enumerate(self._c2w):
            if T is not None:
                out[i] = T
        return out

    def __getitem__(self, i: int) -> Frame:
        return self.frame_at_size(i, *self.size)

    def frame_at_size(self, i: int, width: int, height: int) -> Frame:
        """Frame i at width x height, colour and depth each resampled from the grid it is stored on
        (so depth is never upsampled twice)."""
        n = len(self)
        if not isinstance(i, (int, np.integer)):
            raise TypeError(f"frame index must be an integer, got {type(i).__name__}")
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"frame {i} out of range (capture has {n} frames)")
        i = int(i)
        color = self._read_color(i)
        if (color.shape[1], color.shape[0]) != self.color_size:
            raise InputError(f"{self._name(i, 'color')}: image is {color.shape[1]}x{color.shape[0]}, "
                             f"expected {self.color_size[0]}x{self.color_size[1]} like the other frames")
        depth, n_bad = self._read_depth(i)
        if (depth.shape[1], depth.shape[0]) != self.depth_size:
            raise InputError(f"{self._name(i, 'depth')}: depth is {depth.shape[1]}x{depth.shape[0]}, "
                             f"expected {self.depth_size[0]}x{self.depth_size[1]}")
        self.invalid_depth_pixels += n_bad
        conf = self._read_confidence(i)
        if conf is not None:
            if conf.shape != depth.shape:
                raise InputError(f"{self._name(i, 'confidence')}: confidence map is {conf.shape[1]}x{conf.shape[0]}, "
                                 f"expected the depth size {depth.shape[1]}x{depth.shape[0]}")
            depth = np.where(conf >= self.min_confidence, depth, np.float32(0)).astype(np.float32)
        intr = self._frame_color_intr(i)
        if (width, height) != (intr.width, intr.height):
            intr = intr.scaled(width, height)
        if color.shape[:2] != (intr.height, intr.width):
            color = np.clip(resize_to(color, intr, False), 0.0, 1.0)
        depth = resize_to(depth, intr, True)
        T = self._c2w[i] if self._c2w else None
        return Frame(i, float(self._timestamps[i]), np.ascontiguousarray(color, dtype=np.float32),
                     np.ascontiguousarray(depth, dtype=np.float32), intr, None if T is None else T.copy())

    def describe(self) -> str:
        w, h = self.size
        return f"{self.format_name} capture at {self.path} ({len(self)} frames, {w}x{h})"

    # -- helpers for subclasses
    def warn(self, message: str) -> None:
        self.warnings.append(message)

    def _finish(self, stamps, c2w, what: str) -> None:
        """Store timestamps and poses; refuse an empty capture."""
        self._timestamps = np.asarray(stamps, dtype=np.float64)
        self._c2w = list(c2w)
        if len(self._timestamps) == 0:
            raise InputError(f"{self.path}: no usable frames ({what})")
        n_missing = sum(T is None for T in self._c2w)
        if 0 < n_missing < len(self._c2w):
            self.warn(f"{n_missing} of {len(self._c2w)} frames have no reference pose (kept, without one)")


def sort_by_time(stamps: np.ndarray, name: str, warnings: list[str]) -> np.ndarray:
    """Order that sorts timestamps (stable); warns when the file was not in time order."""
    stamps = np.asarray(stamps, dtype=np.float64)
    order = np.argsort(stamps, kind="stable")
    if np.any(np.diff(stamps) < 0):
        warnings.append(f"{name}: timestamps out of order; sorted by time")
    return order


# ----------------------------------------------------------------------------- file access

class DirStore:
    """Files under a folder, addressed by relative path."""

    def __init__(self, root: Path):
        self.root = Path(root)

    def exists(self, rel: str) -> bool:
        return (self.root / rel).is_file()

    def names(self) -> list[str]:
        return [p.relative_to(self.root).as_posix() for p in self.root.rglob("*") if p.is_file()]

    def read(self, rel: str) -> bytes:
        from .images import read_bytes

        return read_bytes(self.root / rel)

    def label(self, rel: str) -> str:
        return str(self.root / rel)


class ZipStore:
    """Files inside a zip archive (e.g. a Record3D .r3d), read without unpacking.

    When every entry sits under one top folder, names are relative to it.
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        try:
            self._zip = zipfile.ZipFile(self.path)
            entries = [n for n in self._zip.namelist() if not n.endswith("/")]
        except (zipfile.BadZipFile, OSError, EOFError) as e:
            raise InputError(f"{self.path}: not a readable zip archive ({e}); truncated or damaged download?") from None
        tops = {n.split("/", 1)[0] for n in entries}
        self._prefix = ""
        if len(tops) == 1 and all("/" in n for n in entries):
            self._prefix = tops.pop() + "/"
        self._names = {n[len(self._prefix):]: n for n in entries}
        self._lock = threading.Lock()

    def exists(self, rel: str) -> bool:
        return rel in self._names

    def names(self) -> list[str]:
        return list(self._names)

    def read(self, rel: str) -> bytes:
        if rel not in self._names:
            raise InputError(f"{self.label(rel)}: not found in the archive")
        try:
            with self._lock:
                return self._zip.read(self._names[rel])
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError, ValueError) as e:
            raise InputError(f"{self.label(rel)}: cannot read from the archive ({e}); truncated or damaged file?") from None

    def label(self, rel: str) -> str:
        return f"{self.path}:{rel}"


def open_store(path: Path):
    path = Path(path)
    return DirStore(path) if path.is_dir() else ZipStore(path)


# ----------------------------------------------------------------------------- camera files

CAMERA_FILES = ("camera.yaml", "camera.yml", "camera.json", "cam_params.json")


def find_camera_file(folder: Path) -> Path | None:
    for name in CAMERA_FILES:
        if (Path(folder) / name).is_file():
            return Path(folder) / name
    return None


def load_camera_file(path: Path) -> dict:
    """camera.yaml / camera.json (fx fy cx cy width height [depth_scale] [depth_registered_to_rgb])
    or NICE-SLAM's cam_params.json ({"camera": {w h fx fy cx cy scale}}) -> dict with those keys
    as floats, and "registered" (bool) when the file says whether depth is registered to colour."""
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
